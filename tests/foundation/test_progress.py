"""Progress in logs: without a terminal, plain lines with step, loss and ETA at least every 30 s.

Time is a fake clock advanced by hand; nothing sleeps.
"""
import io
import re

import pytest

from rfir_cli import context
from rfir_cli.context import RichReporter
from rfir_core.progress import LineProgress, format_duration


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def _reporter(interval_s=30.0):
    clock, out = Clock(), io.StringIO()
    return LineProgress(out, interval_s=interval_s, clock=clock, heartbeat=False), clock, out


def test_lines_every_interval_with_step_loss_and_eta_and_one_at_the_end():
    rep, clock, out = _reporter()
    stamps = []
    with rep, rep.task("rf-fit", total=100) as task:
        for i in range(100):
            clock.now += 1.0                      # one step a second
            task.update(loss=1.0 / (i + 1))
            before = out.getvalue().count("\n")
            task.advance()
            if out.getvalue().count("\n") > before:
                stamps.append(clock.now)
    lines = out.getvalue().splitlines()
    assert lines[0] == "rf-fit: 30/100 (30%), loss 0.03333, elapsed 30s, ETA 1m10s"
    assert lines[-1] == "rf-fit: 100/100 (100%), loss 0.01, elapsed 1m40s, done"
    assert len(lines) == 4                        # at 30, 60 and 90 s, and the end
    assert all(b - a <= 30.0 for a, b in zip([1000.0] + stamps, stamps))


def test_a_long_step_still_prints_from_the_heartbeat():
    rep, clock, out = _reporter()
    with rep.task("trace", total=4) as task:
        task.advance()
        clock.now += 29.0
        rep.tick()
        assert out.getvalue() == ""               # not quiet long enough yet
        clock.now += 16.0                         # a step of 45 s with no call from the stage
        rep.tick()
        assert out.getvalue().splitlines() == ["trace: 1/4 (25%), elapsed 45s, ETA 2m15s"]
        rep.tick()                                # just printed: nothing new
        assert len(out.getvalue().splitlines()) == 1
    assert out.getvalue().splitlines()[-1].endswith("done")


def test_short_tasks_print_only_their_end_and_errors_print_nothing():
    rep, clock, out = _reporter()
    with rep.task("load", total=None) as task:
        task.advance(3)
    assert out.getvalue().splitlines() == ["load: 3 steps, elapsed 0s, done"]
    with pytest.raises(ValueError), rep.task("fit", total=10) as task:
        clock.now += 100.0
        raise ValueError("bad")
    assert len(out.getvalue().splitlines()) == 1  # the error line belongs to the CLI
    rep.log("a [m] note :A:")
    assert out.getvalue().splitlines()[-1] == "a [m] note :A:"


def test_the_heartbeat_thread_starts_and_stops():
    rep = LineProgress(io.StringIO(), interval_s=3600.0)
    with rep:
        assert rep._thread is not None and rep._thread.is_alive()
        thread = rep._thread
    assert not thread.is_alive()


def test_format_duration():
    assert [format_duration(s) for s in (0.4, 59, 61, 3599, 7500)] == ["0s", "59s", "1m01s", "59m59s", "2h05m"]


def _run_cli_reporter(verbosity=0):
    with RichReporter(verbosity, line_interval_s=0.0) as rep:
        with rep.task("demo", total=2) as task:
            task.advance()
            task.update(loss=0.25)
            task.advance()
        rep.log("note")


def test_the_cli_reporter_prints_lines_without_a_terminal(capsys):
    _run_cli_reporter()
    err = capsys.readouterr().err
    assert "demo: 2/2 (100%), loss 0.25" in err and "note" in err
    assert re.search(r"ETA \d+s", err)


def test_the_cli_reporter_keeps_the_bar_on_a_terminal_and_is_silent_when_quiet(capsys, monkeypatch):
    monkeypatch.setattr(type(context.err_console), "is_terminal", property(lambda self: True))
    _run_cli_reporter()
    assert "demo: 2/2" not in capsys.readouterr().err      # the rich bar, not lines
    monkeypatch.undo()
    _run_cli_reporter(verbosity=-1)
    assert capsys.readouterr().err == ""
