"""The rssi task's antenna grids: points inside furniture or against it are not kept (no solver needed)."""
from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from rfir_core.errors import ConfigError
from rfir_stages.model.room import BLE_CHANNELS_HZ
from rfir_stages.rf_fit.room_stage import simulated_channels
from rfir_stages.simulate.rssi import clear_of_objects
from rfir_stages.simulate.scenes import build_scene
from rfir_stages.simulate.settings import parse_settings
from rfir_stages.simulate.stage import rssi_grids


def _box_distance(spec, pts):
    """[N] m: the distance of each point from the nearest object's bounding box (0 inside one)."""
    out = np.full(len(pts), np.inf)
    for o in spec.objects:
        lo, hi = o.vertices.min(0), o.vertices.max(0)
        gap = np.maximum(np.maximum(lo - pts, pts - hi), 0.0)
        out = np.minimum(out, np.linalg.norm(gap, axis=1))
    return out


def test_flat_grid_drops_exactly_the_points_near_an_object():
    spec = build_scene("flat")
    s = parse_settings(None, scene="flat")
    tx, rx, tx_clear, rx_clear = rssi_grids(spec, s)
    assert tx_clear.all() and len(rx) == 38 * 30
    dist = _box_distance(spec, rx)
    # a point counts as clear when it is outside every box grown by the clearance along each axis
    assert (dist[rx_clear] > s.clearance_m).all()
    assert (dist[~rx_clear] <= s.clearance_m * np.sqrt(3) + 1e-9).all()
    fridge = next(o for o in spec.objects if o.name == "fridge")
    inside = np.all((rx >= fridge.vertices.min(0)) & (rx <= fridge.vertices.max(0)), axis=1)
    assert inside.any() and not rx_clear[inside].any()
    assert 0 < (~rx_clear).sum() < 0.1 * len(rx)


def test_classroom_grid_keeps_every_point():
    spec = build_scene("classroom")
    _, _, tx_clear, rx_clear = rssi_grids(spec, parse_settings(None, scene="classroom"))
    assert tx_clear.all() and rx_clear.all()


def test_no_clearance_keeps_points_outside_boxes_only():
    spec = build_scene("flat")
    s = dataclasses.replace(parse_settings(None, scene="flat"), clearance_m=0.0)
    _, rx, _, rx_clear = rssi_grids(spec, s)
    assert (_box_distance(spec, rx[rx_clear]) > 0).all()
    assert np.array_equal(rx_clear, clear_of_objects(spec, rx, 0.0))


def test_a_grid_wholly_inside_an_object_is_refused():
    spec = build_scene("flat")
    s = dataclasses.replace(parse_settings(None, scene="flat"), tx_height_m=0.0)    # on the floor's box
    with pytest.raises(ConfigError, match="every transmitter grid point"):
        rssi_grids(spec, s)


def test_negative_clearance_is_refused():
    with pytest.raises(ConfigError, match="clearance_m"):
        parse_settings({"rssi": {"clearance_m": -0.1}})


def test_the_flat_is_a_survey_over_bles_channels_and_says_so():
    """The flat's table averages BLE's three advertising channels about the one frequency it solves at; channels
    about several solve frequencies are refused; rf-fit reads the channels from the file's simulator attributes."""
    s = parse_settings(None, scene="flat")
    assert s.rssi_freqs_hz == [2.44e9] and tuple(s.rssi_channels_hz) == BLE_CHANNELS_HZ
    assert parse_settings(None, scene="classroom").rssi_channels_hz == []
    table = {"rssi": {"freqs_hz": [2.4e9, 5.8e9], "channels_hz": [2.402e9]}}
    with pytest.raises(ConfigError, match="channels_hz"):
        parse_settings(table)
    meas = SimpleNamespace(free={"simulator@attrs": {"channels_hz": "2402000000,2426000000,2480000000"}})
    assert simulated_channels(meas) == BLE_CHANNELS_HZ
    assert simulated_channels(SimpleNamespace(free={})) == ()
