"""Regenerate the parameter tables of docs/models/*.md from the registry: python docs/models/params_tables.py (repository root)."""
import sys
import numpy as np
from stabjax.model.registry import SYSTEMS, get_system

def fmt(v):
    a = np.asarray(v, float).ravel()
    return ", ".join(f"{x:.6g}" for x in a)

def table(names):
    first = get_system(names[0])
    rows = {}
    order = []
    for n in names:
        s = get_system(n)
        for p in s.params.params:
            key = p.name
            if key not in rows:
                rows[key] = [p, []]
                order.append(key)
            rows[key][1].append(n)
    out = ["| name | kind | default | unit | meaning |" + (" systems |" if len(names) > 1 else ""),
           "|---|---|---|---|---|" + ("---|" if len(names) > 1 else "")]
    for k in order:
        p, where = rows[k]
        doc = p.doc.replace("|", "\\|")
        line = f"| `{p.name}` | {p.kind} | {fmt(p.default)} | {p.unit} | {doc} |"
        if len(names) > 1:
            line += " all |" if len(where) == len(names) else " " + ", ".join(w.replace('saakyan_', '').replace('twobody_', '') for w in where) + " |"
        out.append(line)
    return "\n".join(out)

groups = {
    "monoaxial": ["monoaxial"],
    "saakyan": [n for n in SYSTEMS if n.startswith("saakyan")],
    "twobody": [n for n in SYSTEMS if n.startswith("twobody")],
    "gyrodyne": ["gyrodyne"],
}
if __name__ == "__main__":
    import re, pathlib
    for g, names in groups.items():
        path = pathlib.Path(f"docs/models/{g}.md")
        if not path.exists():
            continue
        text = path.read_text()
        marker = f"<!-- params:{g} -->"
        tbl = table(names)
        # replace the marker and any table that follows it (up to the next blank line)
        text = re.sub(re.escape(marker) + r"\n(\n?\|.*\n)*", marker + "\n" + tbl + "\n", text)
        path.write_text(text)
        print("updated", path)
