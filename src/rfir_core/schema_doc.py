"""Render the schema as Markdown tables (docs/artifacts.md embeds this output between markers)."""
from __future__ import annotations

from .schema import KINDS, SCHEMA_VERSION

BEGIN, END = "<!-- schema:begin -->", "<!-- schema:end -->"


def schema_markdown() -> str:
    """One section per kind: required root attributes, then a table of fields."""
    out = [f"Schema version **{SCHEMA_VERSION}**.", ""]
    for spec in KINDS.values():
        out += [f"### `{spec.kind}`", "", spec.doc, ""]
        if spec.required_attrs:
            out += ["Required root attributes: " + ", ".join(f"`{a}`" for a in spec.required_attrs) + ".", ""]
        if spec.optional_attrs:
            out += ["| root attribute | type | meaning |", "|---|---|---|"]
            out += [f"| `{a.name}` | {a.dtype}{' (' + ', '.join(a.choices) + ')' if a.choices else ''} | {a.doc} |"
                    for a in spec.optional_attrs]
            out.append("")
        if spec.free_groups:
            out += ["Free-form groups: " + ", ".join(f"`{g}/`" for g in spec.free_groups) + ".", ""]
        out += ["| dataset | dtype | shape | unit | frame | required | meaning |", "|---|---|---|---|---|---|---|"]
        for f in spec.fields:
            shape = "(" + ", ".join(str(s) for s in f.shape) + ")"
            out.append(f"| `{f.name}` | {f.dtype} | {shape} | {f.unit or '-'} | {f.frame or '-'} | "
                       f"{'yes' if f.required else 'no'} | {f.doc} |")
        out.append("")
    return "\n".join(out)


def update_doc(path: str) -> bool:
    """Rewrite the generated part of `path`; True if it changed."""
    with open(path) as handle:
        text = handle.read()
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    new = f"{head}{BEGIN}\n{schema_markdown()}\n{END}{tail}"
    if new != text:
        with open(path, "w") as handle:
            handle.write(new)
    return new != text


if __name__ == "__main__":
    import sys

    update_doc(sys.argv[1] if len(sys.argv) > 1 else "docs/artifacts.md")
