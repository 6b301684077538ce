"""MkDocs hooks of the stabjax site (``hooks:`` in mkdocs.yml): what the pages would otherwise copy by hand.

* ``<!-- table:NAME -->`` in a page becomes a table generated from the code's own declarations (the spec's
  sections, each setting with its type, default and meaning), so the tables cannot drift from the code. Where
  the code declares a setting without a one-line meaning (``IntegrateConfig``'s fields, the ``[refine]`` keys),
  the meaning is written below in ``MEANINGS`` and the build fails when a declared setting has none or a
  written one names a setting that no longer exists. The ``[shock]`` keys (``SHOCK_KEYS``) take their meanings
  from the field table of ``stabjax/explore/shock_config.py``'s docstring, one row per key, under the same rule.
* ``<!-- api:NAME -->`` becomes the mkdocstrings directives of the public names of ``stabjax._API`` (the
  public API), grouped by the subpackage that defines them: a name added to ``_API`` appears on its own.
* A link from a page to a file of the repository outside ``docs/`` (``../results/default.png``,
  ``../../examples/pendulum/model.py``; relative, so that GitHub shows the same page correctly) is copied
  into the site under ``repo/`` and the link rewritten to it.
* The Sphinx roles of the docstrings (``:func:`x```) are shown as code.
"""
from __future__ import annotations

import dataclasses
import inspect
import math
import os
import re
import sys
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File

ROOT = Path(os.path.normpath(Path(__file__).absolute().parents[1]))
if str(ROOT) not in sys.path:  # a clone that is not installed builds its own package's tables
    sys.path.insert(0, str(ROOT))

# ---- meanings the code does not state in one line -------------------------------------------------------

MEANINGS = {
    "top": {
        "system": "the model: a built-in name (`stabjax systems`), `\"path/to/model.py:Class\"` (relative to the "
                  "spec's folder), `\"package.module:Class\"`, or a registered name",
        "name": "the result's name: `results/<name>.nc` unless `--out` says otherwise",
        "description": "free text, kept in the result",
        "params": "fixed values of parameters (overrides of the model's defaults)",
        "grid": "cartesian axes: every combination of their values is a grid point",
        "sample": "random draws (or the starts of a file) repeated at every grid point",
        "integrate": "the solver, the horizon, tolerances, checkpoints and the stops",
        "engine": "the engines' own tuning settings",
        "verdict": "the attitude classifier's thresholds and horizons",
        "outcomes": "named outcomes: rules, templates, escape, discovery (overrides the model's declaration)",
        "refine": "adaptive refinement of the boundary instead of the full grid",
        "shock": "minimal fatal shocks: the smallest perturbation of a start that ends elsewhere, held against a "
                 "theorem's guaranteed region ([Regions of attraction](shock.md))",
    },
    "integrate": {
        "t1": "end of the integration (the horizon); default: the model's `default_t1`",
        "t0": "start time",
        "solver": "the Runge-Kutta method (see the list below)",
        "rtol": "relative tolerance of the step-size controller, in (0, 1)",
        "atol": "absolute tolerance of the step-size controller, in (0, 1)",
        "max_steps": "step budget of one trajectory (status 1 when exhausted)",
        "n_checkpoints": "times at which the observables are folded into the summaries: half log-, half linearly "
                         "spaced, t1 included (8 to 200,000)",
        "dt0": "first step size (default: chosen by the solver)",
        "engine": "`auto` (native, then fused, then diffrax) or one engine's name, tried first",
        "escape_radius": "stop a trajectory once max |y_i| exceeds it (status 100, the escape outcome); "
                         "default: the model's `escape_radius`",
        "early_stop": "stop at a stable fixed point (autonomous models); default: on where it cannot change an "
                      "outcome, off elsewhere ([Stops](stops.md))",
        "attractor_stop": "stop near an attractor the run's first trajectories found (a heuristic, off by "
                          "default; [Stops](stops.md))",
    },
    "refine": {
        "rel_tol": "bracket the boundary to this fraction of each axis range (default 1/64)",
        "tol": "... or in parameter units: one number, or a table per axis (wins over `rel_tol` for the axes "
               "it names)",
        "pair": "only boundaries between these two labels (`\"*\"`: any other label); default: any change",
        "stable": "the label whose region is compared with the theorem (default: `pair[0]`, else `converged`)",
        "label": "`\"verdict\"` or `\"outcome\"` (the default for models with named outcomes)",
        "horizon": "which verdict horizon to refine (default t1) ...",
        "horizons": "... or bracket several in one run: `\"all\"` or a list of horizons",
        "max_points": "refuse to integrate more points than this",
    },
    "dist": {
        "uniform": "uniform on [low, high] (scalar parameters, or each entry of a vector)",
        "normal": "normal with mean and standard deviation",
        "sphere": "uniform on the unit sphere (3-vectors)",
        "cap": "uniform on the spherical cap of `half_angle` (rad) around `center` (a unit 3-vector or the name "
               "of a 3-vector parameter)",
        "ball": "uniform in the ball of `radius` around `center` (default: the origin; 3-vectors)",
        "so3": "uniform (Haar) rotation matrices (3 x 3 parameters)",
    },
    "outcomes": {  # the Outcomes docstring lists the first six; these three are its switches
        "discover": "find the attractors instead of declaring them ([Discovery](outcomes.md#discovered-attractors))",
        "lyapunov": "integrate the largest Lyapunov exponent even when no rule names it",
        "discovery": "the `[outcomes.discovery]` table below",
    },
}
# fields of the settings records that a spec never sets (the plan or the runner does)
NOT_IN_SPECS = {"integrate": {"settings", "known_attractors"}, "verdict": {"verdicts", "t0", "t1", "n_obs"}}


def _fail(msg: str):
    raise PluginError(f"docs/hooks.py: {msg}")


def _cell(x) -> str:
    """A table cell: pipes escaped outside code spans (inside them the backslash would show)."""
    out, last = [], 0
    text = str(x).replace("\n", " ")
    for m in re.finditer(r"(`+).+?(?<!`)\1(?!`)", text):
        out += [text[last:m.start()].replace("|", "\\|"), m[0]]
        last = m.end()
    return "".join(out + [text[last:].replace("|", "\\|")])


def _default(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return f"`{str(v).lower()}`"
    if isinstance(v, float):
        if math.isinf(v):
            return "`inf`"
        return f"`{v:.10g}`"
    if isinstance(v, tuple):
        return "`[]`" if not v else f"`{list(v)}`"
    if isinstance(v, str):
        return f'`"{v}"`'
    return f"`{v}`"


def _kind(f, v) -> str:
    """The TOML type of a record's field, from its annotation (the default may be None: "decided per plan")."""
    t = str(f.type)
    for word, kind in (("Mapping", "table"), ("tuple", "list"), ("bool", "boolean"), ("int", "integer"),
                       ("float", "number"), ("str", "string")):
        if re.search(rf"\b{word}\b", t):
            return kind
    return {bool: "boolean", int: "integer", float: "number", str: "string", tuple: "list", dict: "table"}.get(
        type(v), type(v).__name__)


def field_docs(cls) -> dict[str, str]:
    """The ``name   meaning`` lines of a record's docstring (continuation lines indented), by field name."""
    doc = inspect.getdoc(cls) or ""
    out: dict[str, str] = {}
    current: list[str] = []
    for line in doc.splitlines():
        m = re.match(r"^([a-z_][\w]*(?:, [a-z_]\w*)*)\s{2,}(\S.*)$", line)
        if m:
            current = [n.strip() for n in m[1].split(",")]
            for n in current:
                out[n] = m[2].strip()
        elif current and line.startswith(" ") and line.strip():
            for n in current:
                out[n] += " " + line.strip()
        else:
            current = []
    return out


def rst_field_table(doc: str) -> dict[str, str]:
    """The rows of the reST simple tables of a docstring whose first column is one key in double backquotes
    (``````key``   meaning``, continuation lines indented under the meaning), by key; the meaning's double
    backquotes become Markdown's single ones."""
    out: dict[str, str] = {}
    current = None
    inside = False  # from a border line to the blank line after the table
    for line in doc.splitlines():
        if re.match(r"^=+(\s+=+)+\s*$", line):
            inside, current = True, None
            continue
        if not line.strip():
            inside, current = False, None
            continue
        m = re.match(r"^``(\w+)``\s{2,}(\S.*)$", line) if inside else None
        if m:
            current = m[1]
            out[current] = m[2].strip()
        elif current and line.startswith(" "):
            out[current] += " " + line.strip()
        else:
            current = None
    return {k: v.replace("``", "`") for k, v in out.items()}


def _record_table(cls, section: str, meanings: dict[str, str]) -> str:
    rows = ["| setting | type | default | meaning |", "|---|---|---|---|"]
    names = [f.name for f in dataclasses.fields(cls) if f.name not in NOT_IN_SPECS.get(section, ())]
    missing = [n for n in names if n not in meanings]
    if missing:
        _fail(f"[{section}]: no meaning for {missing} (state it in the docstring of {cls.__name__}, "
              f"or in MEANINGS[{section!r}])")
    for f in dataclasses.fields(cls):
        if f.name in names:
            d = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            rows.append(f"| `{f.name}` | {_kind(f, d)} | {_default(d)} | {_cell(meanings[f.name])} |")
    return "\n".join(rows)


def _written(section: str, declared) -> dict[str, str]:
    written = MEANINGS[section]
    stale = sorted(set(written) - set(declared))
    if stale:
        _fail(f"MEANINGS[{section!r}] names {stale}, which the code no longer declares")
    return written


def table(name: str) -> str:
    """The markdown of the table called ``name``."""
    if name == "top":
        from stabjax.plan.spec import TOP_KEYS

        written = _written("top", TOP_KEYS)
        missing = sorted(TOP_KEYS - set(written))
        if missing:
            _fail(f"top-level keys without a meaning: {missing}")
        rows = ["| key | meaning |", "|---|---|"]
        order = [k for k in written if k in TOP_KEYS]
        return "\n".join(rows + [f"| `{k}` | {_cell(written[k])} |" for k in order])
    if name == "integrate":
        from stabjax.config import IntegrateConfig

        declared = {f.name for f in dataclasses.fields(IntegrateConfig)} - NOT_IN_SPECS["integrate"]
        return _record_table(IntegrateConfig, "integrate", _written("integrate", declared))
    if name == "solvers":
        from stabjax.config import SOLVERS

        return ", ".join(f"`{s}`" for s in SOLVERS)
    if name == "engines":
        from stabjax.engines import CHOICES

        return ", ".join(f"`{s}`" for s in CHOICES)
    if name == "engine":
        from stabjax.engines import SETTINGS

        rows = ["| setting | engine | values | changes results | meaning |", "|---|---|---|---|---|"]
        for eng, settings in SETTINGS.items():
            for s in settings:
                doc = re.sub(r"^\w+ engine: ", "", s.doc)
                changes = "yes: part of the run's identity" if s.changes_results else "no"
                rows.append(f"| `{s.name}` | {eng} | {s.lo} … {s.hi} (default {s.default}) | {changes} | {_cell(doc)} |")
        return "\n".join(rows)
    if name == "verdict":
        from stabjax.config import VerdictConfig

        return _record_table(VerdictConfig, "verdict", field_docs(VerdictConfig))
    if name == "outcomes":
        from stabjax.model.outcomes import Outcomes

        docs = {**field_docs(Outcomes), **_written("outcomes", Outcomes.KEYS)}
        extra = sorted(set(docs) - set(Outcomes.KEYS))
        if extra:
            _fail(f"Outcomes' docstring describes {extra}, which are not keys of [outcomes]")
        return _record_table(Outcomes, "outcomes", docs)
    if name == "discovery":
        from stabjax.model.outcomes import DiscoveryConfig

        return _record_table(DiscoveryConfig, "discovery", field_docs(DiscoveryConfig))
    if name == "refine":
        from stabjax.explore.refine_config import REFINE_KEYS

        written = _written("refine", REFINE_KEYS)
        missing = [k for k in REFINE_KEYS if k not in written]
        if missing:
            _fail(f"[refine] keys without a meaning: {missing}")
        return "\n".join(["| key | meaning |", "|---|---|"] + [f"| `{k}` | {_cell(written[k])} |" for k in REFINE_KEYS])
    if name == "shock":
        from stabjax.explore import shock_config

        rows = rst_field_table(inspect.getdoc(shock_config) or "")
        keys = shock_config.SHOCK_KEYS
        missing = [k for k in keys if k not in rows]
        if missing:
            _fail(f"[shock] keys without a meaning: {missing} (a row each in the field table of the docstring of "
                  "stabjax/explore/shock_config.py)")
        stale = sorted(set(rows) - set(keys))
        if stale:
            _fail(f"the field table of stabjax/explore/shock_config.py names {stale}, which are not [shock] keys")
        return "\n".join(["| key | meaning |", "|---|---|"] + [f"| `{k}` | {_cell(rows[k])} |" for k in keys])
    if name == "dists":
        from stabjax.plan.samplers import _DISTS, _REQUIRED

        written = _written("dist", _DISTS)
        missing = sorted(set(_DISTS) - set(written))
        if missing:
            _fail(f"sample distributions without a meaning: {missing}")
        rows = ["| `dist` | keys (required in bold) | draws |", "|---|---|---|"]
        for d, keys in _DISTS.items():
            ks = ", ".join(f"**`{k}`**" if k in _REQUIRED.get(d, ()) else f"`{k}`" for k in sorted(keys)) or "—"
            rows.append(f"| `\"{d}\"` | {ks} | {_cell(written[d])} |")
        return "\n".join(rows)
    if name == "status":
        from stabjax.fold import status as S

        rows = ["| `solver_status` | name | meaning |", "|---|---|---|"]
        doc = inspect.getdoc(S) or ""
        for code, nm in sorted(S.NAMES.items()):
            const = next(k for k in ("OK", "MAX_STEPS", "ESCAPED") if getattr(S, k) == code)
            m = re.search(rf"^{const}\s+{code}\s+(.*?)(?=^\S|^=)", doc, re.M | re.S)
            if not m:
                _fail(f"stabjax.fold.status: no meaning for {const} in the module docstring")
            rows.append(f"| {code} | `{nm}` | {_cell(' '.join(m[1].split()))} |")
        rows.append("| other | diffrax's code | another solver failure: "
                    f"{', '.join(S.DIFFRAX_RESULTS[2:])} |")
        return "\n".join(rows)
    if name == "commands":
        import typer

        from stabjax.app.cli import app

        group = typer.main.get_command(app)
        rows = ["| command | what it does |", "|---|---|"]
        for cmd_name in sorted(group.commands):
            cmd = group.commands[cmd_name]
            if cmd.hidden:
                continue
            first = " ".join((cmd.help or "").split("\n\n")[0].split())  # the docstring's first paragraph
            rows.append(f"| `stabjax {cmd_name}` | {_cell(first)} |")
        return "\n".join(rows)
    _fail(f"unknown table {name!r}")


# ---- the public API -----------------------------------------------------------------------------------

API_GROUPS = (  # (title, the subpackages whose public names it holds)
    ("Run", ("run", "plan", "engines", "explore")),
    ("See a result", ("present",)),
    ("Write a model", ("model",)),
    ("Settings and errors", ("config", "errors")),
)
DETAIL_PAGE = "api/model.md"  # the model-writing names, with every member


def api(which: str) -> str:
    import stabjax

    groups: dict[str, list[str]] = {t: [] for t, _ in API_GROUPS}
    for pub, mod in stabjax._API.items():
        top = mod.split(".")[0]
        title = next((t for t, pkgs in API_GROUPS if top in pkgs), "Other")
        groups.setdefault(title, []).append(pub)
    out = []
    if which == "public":
        for title, names in groups.items():
            if not names:
                continue
            out.append(f"## {title}\n")
            if title == "Write a model":
                out.append("In detail, with every member: [Writing a model](model.md): "
                           + ", ".join(f"[`{n}`](model.md#stabjax.{n})" for n in names) + ".\n")
                continue
            for n in names:
                out.append(f"::: stabjax.{n}\n    options:\n      heading_level: 3\n      show_root_full_path: false\n"
                           "      show_root_heading: true\n      members: false\n")
        return "\n".join(out)
    if which == "model":
        for n in groups["Write a model"]:
            out.append(f"::: stabjax.{n}\n    options:\n      heading_level: 2\n      show_root_full_path: false\n"
                       "      show_root_heading: true\n")
        return "\n".join(out)
    _fail(f"unknown api block {which!r}")


# ---- hooks --------------------------------------------------------------------------------------------

_LINK = re.compile(r"(\]\()([^)\s#]+)((?:#[^)\s]*)?\))")
_REPO = "repo"  # where linked repository files go in the site


def _outside_links(page_path: Path, text: str):
    """(match, repository path) of each relative link of the page to an existing repository file outside docs/."""
    for m in _LINK.finditer(text):
        target = m[2]
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("/"):
            continue
        p = Path(os.path.normpath(page_path.parent / target))  # symlinks kept: examples/, not stabjax/examples/
        try:
            rel = p.relative_to(ROOT)
        except ValueError:
            continue
        if rel.parts and rel.parts[0] != "docs" and p.is_file():
            yield m, rel


def on_files(files, config):
    docs = Path(os.path.normpath(config["docs_dir"]))
    seen = set()
    for f in list(files):
        if not f.src_uri.endswith(".md"):
            continue
        path = docs / f.src_uri
        for _, rel in _outside_links(path, path.read_text(encoding="utf-8")):
            if rel not in seen:
                seen.add(rel)
                files.append(File.generated(config, f"{_REPO}/{rel.as_posix()}", abs_src_path=str(ROOT / rel)))
    return files


def on_page_markdown(markdown, page, config, files):
    path = Path(os.path.normpath(config["docs_dir"])) / page.file.src_uri

    def link(m):
        for mm, rel in _outside_links(path, m[0]):
            up = "../" * (len(Path(page.file.src_uri).parts) - 1)
            return f"{m[1]}{up}{_REPO}/{rel.as_posix()}{m[3]}"
        return m[0]

    markdown = _LINK.sub(link, markdown)
    markdown = re.sub(r"<!-- table:(\w+) -->", lambda m: table(m[1]), markdown)
    markdown = re.sub(r"<!-- api:(\w+) -->", lambda m: api(m[1]), markdown)
    return markdown


_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|exc|obj):(?=<code>)")


def on_page_content(html, page, config, files):
    html = _ROLE.sub("", html)
    return re.sub(r"<code>~(?:[\w]+\.)*(\w+)</code>", r"<code>\1</code>", html)
