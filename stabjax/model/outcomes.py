"""Named outcomes, as a model declares them: the declaration and its rule language.

A system (or a spec's ``[outcomes]`` table) declares its outcomes; every trajectory gets one integer
code, stored as the dataset variable ``outcome`` with CF ``flag_values`` / ``flag_meanings``. The
declaration (:class:`Outcomes`) says which outcomes there are and how to recognise them; assigning
them is the mapping's (:mod:`stabjax.mapping.mapper`: one mapper per plan). Codes are, in this order:

1. the **rule** outcomes, in declaration order: the first rule that holds wins. A rule is an
   expression over *late-window features* of the observables (``max(x)``, ``min(x)``,
   ``mean(x)``, ``std(x)``, ``final(x)``: over the checkpoints with ``t >= t0 + (1 - window)(t1 - t0)``),
   numbers and the system's scalar parameters, with ``+ - * / **``, ``abs``, comparisons,
   ``and``/``or``/``not``; e.g. ``"std(omega) < 1e-3 and abs(mean(omega)) < 1e-3"``;
2. the **template** outcomes: each template is an initial condition (parameter overrides) that
   is integrated with the same settings at every grid point; a trajectory that no rule claimed is
   given the template whose feature vector (``features``, a list of feature expressions) is
   nearest, if that distance is below ``max_distance`` (default: half the smallest distance
   between two templates' feature vectors, so the assignment is never a close call between two);
3. ``escaped`` (renamed by ``escape = "unbounded"``) when the system or spec sets
   ``escape_radius``: the integration stops once max_i |y_i| exceeds it;
4. ``unclassified``: no rule holds and no template is near;
5. ``failed``: the solver did not reach t1 (max steps, step-size collapse, NaN), or an observable
   that the outcome reads is NaN or infinite in the window (:func:`finite_features`).

Nothing is absorbed silently: 4 and 5 are always present (:mod:`stabjax.mapping.declared`). A system
that declares no outcomes gets its attractors discovered (:mod:`stabjax.mapping.discover`:
``fixed_point_1``, ``limit_cycle_1``, ``chaotic_1``, ...), and so does a spec with ``[outcomes]
discover = true``; ``[outcomes.discovery]`` (:class:`DiscoveryConfig`) sets how, and never chooses
discovery by itself. The attitude models declare ``outcomes = VERDICTS``: their verdicts are their
outcomes (converged, flipped, diverged, undecided, failed), with the same codes as ``verdict``.
Basin stability over the codes: :mod:`stabjax.mapping.basin`.
"""
from __future__ import annotations

import ast
import functools
import math
import operator
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

import numpy as np

from ..errors import ValidationError

FEATURES = ("max", "min", "mean", "std", "final")
LYAPUNOV = "lyapunov"  # bare name in rules and features: the largest Lyapunov exponent (stabjax.model.tangent)
UNCLASSIFIED, FAILED_NAME, ESCAPED_NAME = "unclassified", "failed", "escaped"
MAX_RULE_CHARS = 500

# named outcomes, in declaration order: Okabe & Ito's colour-blind-safe palette (blue, vermillion, bluish
# green, reddish purple, orange, sky blue, yellow), then darker tones; greys stay for unclassified/failed
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#F0E442", "#5f0f40", "#264653",
           "#8d6e00")
GREY_UNCLASSIFIED, GREY_FAILED, COLOR_ESCAPED = "#adb5bd", "#6c757d", "#8d0801"


# ---- rule expressions ---------------------------------------------------------------------------

_BIN = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv,
        ast.Pow: operator.pow}
_CMP = {ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge,
        ast.Eq: operator.eq, ast.NotEq: operator.ne}
_CONST = {"pi": math.pi, "e": math.e, "inf": math.inf}


class Rule:
    """A parsed rule or feature expression; evaluated vectorised on feature arrays.

    ``features(stat, observable) -> array (N,)``; ``params(name) -> array (N,)``.
    """

    def __init__(self, text: str, observables: tuple[str, ...], params: tuple[str, ...], field: str,
                 boolean: bool = True):
        self.text, self.field = text, field
        if not isinstance(text, str) or not text.strip():
            raise ValidationError(field, f"must be a non-empty expression string, got {text!r}")
        if len(text) > MAX_RULE_CHARS:
            raise ValidationError(field, f"expression longer than {MAX_RULE_CHARS} characters")
        try:
            self.tree = ast.parse(text.strip(), mode="eval").body
        except SyntaxError as exc:
            raise ValidationError(field, f"cannot parse {text!r}: {exc.msg}") from None
        self.observables, self.params = observables, params
        self.used: set[tuple[str, str]] = set()
        kind = self._check(self.tree)
        if boolean and kind != "bool":
            raise ValidationError(field, f"{text!r} is not a condition (use a comparison, e.g. 'std(x) < 1e-3')")
        if not boolean and kind != "num":
            raise ValidationError(field, f"{text!r} must be a number-valued feature expression, e.g. 'max(x)'")

    def _err(self, msg: str):
        return ValidationError(self.field, f"{self.text!r}: {msg}")

    def _check(self, node) -> str:
        """Type-check the tree ('num' or 'bool'); only whitelisted nodes pass."""
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise self._err(f"only numbers are allowed as constants, got {node.value!r}")
            try:
                finite = math.isfinite(float(node.value))
            except OverflowError:  # an integer literal beyond any double
                finite = False
            if not finite:
                raise self._err("non-finite constant")
            return "num"
        if isinstance(node, ast.Name):
            if node.id in _CONST or node.id in self.params:
                return "num"
            if node.id == LYAPUNOV:  # the largest Lyapunov exponent over the window (stabjax.model.tangent)
                self.used.add(("final", LYAPUNOV))
                return "num"
            if node.id.lower() == "nan":  # the user meant a number, not a name to suggest max(nan) for
                raise self._err("NaN is not allowed here: give a number")
            raise self._err(f"unknown name {node.id!r}; use a feature such as max({node.id}) for observables, "
                            f"or one of the parameters {', '.join(self.params)}")
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.keywords or len(node.args) != 1:
                raise self._err("calls take one argument: max(x), min(x), mean(x), std(x), final(x), abs(expr)")
            fn = node.func.id
            if fn == "abs":
                if self._check(node.args[0]) != "num":
                    raise self._err("abs() takes a number")
                return "num"
            if fn not in FEATURES:
                raise self._err(f"unknown function {fn!r}; features: {', '.join(FEATURES)}; and abs()")
            arg = node.args[0]
            if not isinstance(arg, ast.Name) or arg.id not in self.observables:
                raise self._err(f"{fn}() takes an observable name: {', '.join(self.observables)}")
            self.used.add((fn, arg.id))
            return "num"
        if isinstance(node, ast.UnaryOp):
            k = self._check(node.operand)
            if isinstance(node.op, ast.Not):
                if k != "bool":
                    raise self._err("'not' needs a condition")
                return "bool"
            if isinstance(node.op, (ast.USub, ast.UAdd)) and k == "num":
                return "num"
            raise self._err("unsupported unary operator")
        if isinstance(node, ast.BinOp):
            if type(node.op) not in _BIN:
                raise self._err("only + - * / ** are allowed")
            if self._check(node.left) != "num" or self._check(node.right) != "num":
                raise self._err("arithmetic on a condition")
            self._constant_is_finite(node)
            return "num"
        if isinstance(node, ast.Compare):
            for op in node.ops:
                if type(op) not in _CMP:
                    raise self._err("only < <= > >= == != comparisons are allowed")
            for x in [node.left, *node.comparators]:
                if self._check(x) != "num":
                    raise self._err("comparisons take numbers")
            return "bool"
        if isinstance(node, ast.BoolOp):
            for v in node.values:
                if self._check(v) != "bool":
                    raise self._err("'and'/'or' combine conditions")
            return "bool"
        raise self._err(f"unsupported syntax ({type(node).__name__})")

    def _constant_is_finite(self, node) -> None:
        """Refuse arithmetic on constants alone that is not finite (``1/0``, ``10.0**400``): evaluated
        here, statically, it would otherwise make the rule always true or always false without a word."""
        if any(isinstance(n, ast.Call) or (isinstance(n, ast.Name) and n.id not in _CONST) for n in ast.walk(node)):
            return
        if any(isinstance(n, ast.Name) and not math.isfinite(_CONST[n.id]) for n in ast.walk(node)):
            return  # ``inf`` written on purpose
        with np.errstate(all="ignore"):
            v = self._eval(node, None, None)
        if not np.isfinite(v):
            raise self._err(f"{ast.unparse(node)} evaluates to {float(v)}, not a finite number")

    def __call__(self, feat, params) -> np.ndarray:
        with np.errstate(all="ignore"):
            return np.asarray(self._eval(self.tree, feat, params))

    def _eval(self, node, feat, params):
        # numpy scalars, not Python floats: 1/0 on features is inf (numpy), never a ZeroDivisionError
        # raised after the whole integration
        if isinstance(node, ast.Constant):
            return np.float64(node.value)
        if isinstance(node, ast.Name):
            if node.id in _CONST:
                return np.float64(_CONST[node.id])
            return params(node.id) if node.id in self.params else feat("final", LYAPUNOV)
        if isinstance(node, ast.Call):
            if node.func.id == "abs":
                return np.abs(self._eval(node.args[0], feat, params))
            return feat(node.func.id, node.args[0].id)
        if isinstance(node, ast.UnaryOp):
            v = self._eval(node.operand, feat, params)
            return np.logical_not(v) if isinstance(node.op, ast.Not) else (-v if isinstance(node.op, ast.USub) else v)
        if isinstance(node, ast.BinOp):
            left, right = self._eval(node.left, feat, params), self._eval(node.right, feat, params)
            if isinstance(node.op, ast.Pow):
                # bounded: a rule is evaluated on feature arrays, never on huge integers
                return np.power(np.asarray(left, float), np.asarray(right, float))
            return _BIN[type(node.op)](left, right)
        if isinstance(node, ast.Compare):
            vals = [self._eval(x, feat, params) for x in [node.left, *node.comparators]]
            out = True
            for op, a, b in zip(node.ops, vals[:-1], vals[1:]):
                out = np.logical_and(out, _CMP[type(op)](a, b))
            return out
        if isinstance(node, ast.BoolOp):
            vals = [self._eval(v, feat, params) for v in node.values]
            f = np.logical_and if isinstance(node.op, ast.And) else np.logical_or
            out = vals[0]
            for v in vals[1:]:
                out = f(out, v)
            return out
        raise AssertionError(type(node))


def _trial(rule: Rule, observables: tuple[str, ...], params: tuple[str, ...]) -> None:
    """Evaluate a rule once on made-up features and parameters, before anything is integrated: an
    expression that cannot be evaluated fails here, naming its field, not after the whole run."""
    probe = np.array([-2.0, -0.5, 0.0, 0.5, 2.0])
    try:
        out = rule(lambda stat, obs: probe, lambda name: probe)
        np.broadcast_to(out, probe.shape)
    except Exception as exc:  # noqa: BLE001 - any failure of a user's expression is a bad input
        raise ValidationError(rule.field, f"{rule.text!r} cannot be evaluated ({type(exc).__name__}: {exc})") from None


@functools.lru_cache(maxsize=256)
def parse(text: str, observables: tuple[str, ...], params: tuple[str, ...], field: str, boolean: bool = True) -> Rule:
    """A :class:`Rule`, parsed and checked once per text and system (assignment runs chunk by chunk)."""
    return Rule(text, observables, params, field, boolean)


def _names(system) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(observables, scalar parameters): the names a rule may use."""
    return tuple(system.observables), tuple(p.name for p in system.params if not p.shape)


# ---- declarations ----------------------------------------------------------------------------------


class _Verdicts:
    """The declaration ``outcomes = VERDICTS``: the outcomes are the attitude verdicts (converged,
    flipped, diverged, undecided, failed) of :mod:`stabjax.fold.verdict`, whose rules read observable 0
    as an error metric and observable 1 as a size. The built-in attitude systems declare it; a model
    that declares nothing gets its attractors discovered (:mod:`stabjax.mapping.discover`) instead."""

    def __repr__(self):
        return "VERDICTS"

    def __reduce__(self):
        return "VERDICTS"


VERDICTS = _Verdicts()


MIN_SUBSAMPLE = 1000  # the smallest [outcomes.discovery] subsample (DiscoveryConfig)
MIN_EPS = 1e-12  # the least DBSCAN radius in scaled features (DiscoveryConfig.eps)


@dataclass(frozen=True)
class DiscoveryConfig:
    """``[outcomes.discovery]``: the grouping, typing and continuation settings of attractor discovery
    (:mod:`stabjax.mapping.discover`). Defaults measured on the examples (``docs/performance.md``:
    eps = 0.05 is the one value of 0.01 ... 0.2 that neither tears a chaotic attractor's feature cloud
    nor merges Duffing's period-3 cycles).

    The table configures discovery; it does not switch it on. Discovery runs for a model that declares no
    outcomes, or with ``[outcomes] discover = true``; the table beside a model's rules, templates or
    verdicts is refused naming it (as Attractors.jl and pyBasin take a mapper or predictor as an object
    the user chooses, never from the presence of one of its settings; and a setting that would be
    ignored is refused, like any unknown key).

    eps              DBSCAN radius, in units of each observable's range over the sweep
    min_samples      DBSCAN: neighbours within eps (itself included) that make a core sample; a sweep (or,
                     under continuation, a grid point) with fewer trajectories is refused before integrating
    subsample        trajectories grouped by DBSCAN itself; the others join their nearest core sample
                     (at least ``MIN_SUBSAMPLE`` = 1000: it changes the speed, not the partition)
    fixed_point_tol  window std / range below this for every observable -> fixed point (so is a window
                     std within the fixed-point stop's 1000 solver tolerances, and a group the stop froze)
    chaos_threshold  median largest Lyapunov exponent above this -> chaotic; below minus this, an
                     autonomous model's group (or any monotone approach) is a fixed point still approaching
    lyapunov         integrate the tangent dynamics for the exponent (off: no chaotic/limit-cycle types)
    seed             of the subsample
    continuation     with one ``[grid]`` axis and ``[sample]``: group each grid point on its own and match
                     the attractors of neighbouring points (:mod:`stabjax.mapping.continuation`), so each
                     keeps its name along the axis and births and deaths are reported
                     (``attractor_events``); a group matches only an attractor of its own type. false:
                     group all points together (an attractor keeps one name across the grid by the
                     pooled grouping)
    match_threshold  the representatives of one attractor at neighbouring grid points lie less than this
                     apart (scaled features, the units of eps); a longer jump is a death and a birth.
                     Default (unset): from the data, the smallest distance between two attractors found at
                     one grid point -- a jump that long is the step from one attractor to another
                     (unbounded where no point holds two; the types still split); ``inf``: the greedy
                     order alone decides (Attractors.jl's ``MatchBySSSetDistance`` default). The value
                     used is the ``match_threshold`` attribute of ``attractor_events``
    """

    eps: float = 0.05
    min_samples: int = 5
    subsample: int = 4000
    fixed_point_tol: float = 1e-4
    chaos_threshold: float = 0.01
    lyapunov: bool = True
    seed: int = 0
    continuation: bool = True
    match_threshold: float | None = None  # None: from the data (mapping.continuation.default_threshold)

    @classmethod
    def from_dict(cls, d: Any, section: str = "outcomes.discovery") -> "DiscoveryConfig":
        if d is None:
            return cls()
        if not isinstance(d, Mapping):
            raise ValidationError(section, "must be a table")
        known = {f.name: f for f in fields(cls)}
        kw = {}
        for k, v in d.items():
            if k not in known:
                raise ValidationError(f"{section}.{k}", f"unknown key; known: {', '.join(known)}")
            default = known[k].default
            if isinstance(default, bool):
                if not isinstance(v, bool):
                    raise ValidationError(f"{section}.{k}", f"must be true or false, got {v!r}")
            elif isinstance(default, int):
                if isinstance(v, bool) or not isinstance(v, int) or v < (0 if k == "seed" else 1):
                    what = "a non-negative integer" if k == "seed" else "a positive integer"
                    raise ValidationError(f"{section}.{k}", f"must be {what}, got {v!r}")
                if k == "subsample" and v < MIN_SUBSAMPLE:
                    # DBSCAN's density on a small draw depends on which trajectories were drawn: at 6 of 200
                    # the pendulum's one running cycle came out as three
                    raise ValidationError(f"{section}.{k}", f"must be at least {MIN_SUBSAMPLE} (a smaller draw "
                                          f"splits attractors by chance; a sweep of fewer trajectories is grouped "
                                          f"whole), got {v!r}")
            else:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or (
                        math.isinf(v) and k != "match_threshold"):
                    raise ValidationError(f"{section}.{k}", f"must be a finite number, got {v!r}")
                if k == "chaos_threshold" and v < 0:  # 0: the sign of the exponent alone types
                    raise ValidationError(f"{section}.{k}", f"must be >= 0 (a negative one would call an equilibrium "
                                                           f"chaotic), got {v!r}")
                if k != "chaos_threshold" and not v > 0:
                    raise ValidationError(f"{section}.{k}", f"must be > 0, got {v!r}")
                if k == "eps" and v < MIN_EPS:
                    # features scaled to their ranges are known to float64's ~1e-16 at best, and to the solver's
                    # tolerance in fact: a radius below that groups by rounding (1e-300 made both wells of a double
                    # well one group)
                    raise ValidationError(f"{section}.{k}", f"must be at least {MIN_EPS:g} (the features, scaled to "
                                          f"their ranges, are not resolved more finely), got {v!r}")
                v = float(v)
            kw[k] = v
        return cls(**kw)


@dataclass
class Outcomes:
    """A system's outcome declaration (see the module docstring).

    rules         name -> condition over late-window features (first match wins)
    templates     name -> parameter overrides (an initial condition on the attractor's basin)
    features      feature expressions compared between trajectories and templates
    max_distance  largest feature distance to a template (None: half the smallest template spacing)
    window        the features use the last ``window`` fraction of [t0, t1] (0 < window <= 1)
    escape        name of the outcome of trajectories stopped at ``escape_radius``
    """

    rules: Mapping[str, str] = field(default_factory=dict)
    templates: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    features: tuple[str, ...] = ()
    max_distance: float | None = None
    window: float = 0.5
    escape: str = ESCAPED_NAME
    discover: bool = False
    lyapunov: bool = False
    discovery: Mapping[str, Any] = field(default_factory=dict)

    KEYS = ("rules", "templates", "features", "max_distance", "window", "escape", "discover", "lyapunov",
            "discovery")

    def uses_lyapunov(self, system) -> bool:
        """Whether the tangent dynamics must be integrated: asked for (``lyapunov = true``), used by a
        rule or a template feature, or discovery (which types attractors by the exponent unless
        ``[outcomes.discovery] lyapunov = false``)."""
        if self.lyapunov:
            return True
        if self.discover and self.discovery.get("lyapunov", True):
            return True
        obs, scalars = _names(system)
        texts = [(t, True) for t in self.rules.values()]
        texts += [(t, False) for t in (self.features if self.templates else ())]
        for t, boolean in texts:
            try:
                if ("final", LYAPUNOV) in parse(t, obs, scalars, "outcomes", boolean).used:
                    return True
            except ValidationError:
                pass  # reported by check()
        return False

    @classmethod
    def from_spec(cls, table: Any, base: "Outcomes | None" = None, section: str = "outcomes") -> "Outcomes":
        """The spec's ``[outcomes]`` table; keys not given keep the system's declaration."""
        if not isinstance(table, Mapping):
            raise ValidationError(section, "must be a table")
        unknown = set(table) - set(cls.KEYS)
        if unknown:
            raise ValidationError(f"{section}.{sorted(unknown)[0]}", f"unknown key; known: {', '.join(cls.KEYS)}")
        base = base or cls()
        kw = {k: getattr(base, k) for k in cls.KEYS}
        for k in ("rules", "templates"):
            if k in table:
                if not isinstance(table[k], Mapping):
                    raise ValidationError(f"{section}.{k}", "must be a table of name = ...")
                kw[k] = dict(table[k])
        if "features" in table:
            if not isinstance(table["features"], list):
                raise ValidationError(f"{section}.features", "must be a list of feature expressions")
            kw["features"] = tuple(table["features"])
        for k in ("max_distance", "window"):
            if k in table:
                v = table[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise ValidationError(f"{section}.{k}", f"must be a finite number, got {v!r}")
                kw[k] = float(v)
        if "escape" in table:
            kw["escape"] = table["escape"]
        for k in ("discover", "lyapunov"):
            if k in table:
                if not isinstance(table[k], bool):
                    raise ValidationError(f"{section}.{k}", f"must be true or false, got {table[k]!r}")
                kw[k] = table[k]
        if "discovery" in table:
            DiscoveryConfig.from_dict(table["discovery"], f"{section}.discovery")  # checked now
            kw["discovery"] = dict(table["discovery"])
        if ("rules" in table or "templates" in table) and "discover" not in table:
            kw["discover"] = False  # declared outcomes replace a discovering base declaration
        if "discovery" in table and not kw["discover"]:
            # the table configures discovery, it never chooses it (DiscoveryConfig): settings that would be
            # ignored are refused, and declared outcomes are never replaced by the presence of a setting
            raise ValidationError(f"{section}.discovery", "configures attractor discovery, which is off here: the "
                                  "outcomes are declared (the model's or this table's rules, templates or verdicts); "
                                  f"set {section}.discover = true to discover the attractors instead, or remove "
                                  f"[{section}.discovery]")
        if kw["discover"] and "rules" not in table and "templates" not in table:
            kw["rules"], kw["templates"] = {}, {}  # discovery replaces the model's declared outcomes
        return cls(**kw)

    def names(self, escape: bool) -> tuple[str, ...]:
        return (tuple(self.rules) + tuple(self.templates) + ((self.escape,) if escape else ())
                + (UNCLASSIFIED, FAILED_NAME))

    def check(self, system, where: str = "outcomes", escape: bool = False) -> None:
        """Validate names, rules, templates and features against the system."""
        obs, scalars = _names(system)
        if not (self.rules or self.templates or self.discover):
            raise ValidationError(where, "declares no outcome (give rules and/or templates, or discover = true)")
        if self.discover and (self.rules or self.templates):
            raise ValidationError(f"{where}.discover", "discovery finds the outcomes itself: give no rules or "
                                  "templates with discover = true")
        names = self.names(escape=True)
        for n in names:
            if not isinstance(n, str) or not n.isidentifier():
                raise ValidationError(where, f"outcome name {n!r} is not an identifier")
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValidationError(where, f"outcome name(s) used twice or reserved: {', '.join(dup)}")
        if not (isinstance(self.window, (int, float)) and 0 < self.window <= 1):
            raise ValidationError(f"{where}.window", f"must be in (0, 1], got {self.window!r}")
        for name, text in self.rules.items():
            _trial(parse(text, obs, scalars, f"{where}.rules.{name}"), obs, scalars)
        if self.templates:
            if not self.features:
                raise ValidationError(f"{where}.features", "templates need features, e.g. [\"max(x)\", \"std(x)\"]")
            for i, text in enumerate(self.features):
                _trial(parse(text, obs, scalars, f"{where}.features[{i}]", boolean=False), obs, scalars)
            seen: dict[str, str] = {}
            for name, over in self.templates.items():
                if not isinstance(over, Mapping) or not over:
                    raise ValidationError(f"{where}.templates.{name}", "must be a table of parameter overrides")
                try:
                    resolved = system.params.resolve(over)
                except ValidationError as exc:
                    raise ValidationError(f"{where}.templates.{name}.{exc.field}", exc.message) from None
                # the same initial condition twice: the two feature vectors coincide at every grid point
                key = repr(sorted((k, np.asarray(resolved[k]).tolist()) for k in over))
                if key in seen:
                    raise ValidationError(f"{where}.templates.{name}", f"the same initial condition as "
                                          f"{where}.templates.{seen[key]} (feature distance 0): the two templates "
                                          "coincide and no trajectory could be told between them; drop one")
                seen[key] = name
        if self.max_distance is not None and not self.max_distance > 0:
            raise ValidationError(f"{where}.max_distance", f"must be > 0, got {self.max_distance}")

    def observables_read(self, system) -> tuple[str, ...]:
        """The observables (and ``lyapunov``) that the rules and the template features name: a non-finite
        value in any of them makes a trajectory failed (:func:`finite_features`), whichever statistic of it
        a rule happens to read."""
        obs, scalars = _names(system)
        texts = [(t, True) for t in self.rules.values()]
        texts += [(t, False) for t in (self.features if self.templates else ())]
        read: set[str] = set()
        for t, boolean in texts:
            read |= {o for _, o in parse(t, obs, scalars, "outcomes", boolean).used}
        return tuple(o for o in (*obs, LYAPUNOV) if o in read)

    def default_distance_note(self, where: str = "outcomes") -> str:
        """One line for the user when the template distance is unbounded ("" otherwise): with a single
        template and no ``max_distance``, every trajectory that no rule claims is assigned to it."""
        if len(self.templates) == 1 and self.max_distance is None:
            (name,) = self.templates
            return (f"{where}: one template ({name}) and no max_distance: the default distance is unbounded, so "
                    f"every trajectory that no rule claims is counted as {name}; set {where}.max_distance to bound it")
        return ""


def feature_getter(results: Mapping[str, np.ndarray], observables: tuple[str, ...]):
    """``feat(stat, observable)`` over the engine's ``feat_<stat>`` arrays (N, n_obs)."""
    index = {o: i for i, o in enumerate(observables)}

    def feat(stat, obs):
        if obs == LYAPUNOV and obs not in index:
            if LYAPUNOV not in results:
                raise ValueError("the rules use the Lyapunov exponent but it was not integrated")
            return np.asarray(results[LYAPUNOV])
        return np.asarray(results[f"feat_{stat}"])[:, index[obs]]

    return feat


def finite_features(results: Mapping[str, np.ndarray], observables: tuple[str, ...],
                    read: tuple[str, ...] | None = None) -> np.ndarray:
    """(N,) True where every late-window feature (max, min, mean, std, final) of the observables ``read``
    (default: all) is finite, and ``lyapunov`` too when read.

    A NaN or infinite observable in the window is a numerical failure that the solver need not see (an
    observable such as sqrt(x) of a state that went negative): a comparison with NaN is False, so a
    catch-all rule (``not (...)``) would claim the trajectory and discovery would leave it unclassified.
    All five statistics are checked, not only the one a rule names: the fixed-point stop writes std = 0
    at an equilibrium whose observables are NaN (:func:`stabjax.fold.stops.at_equilibrium`), and the native
    engine's max and min can drop a NaN followed by a number (one select, :mod:`stabjax.engines.native.emit`)
    where the sum (the mean) keeps it on every engine.
    """
    index = {o: i for i, o in enumerate(observables)}
    cols = [index[o] for o in (observables if read is None else read) if o in index]
    n = len(np.asarray(results["solver_status"]))
    ok = np.ones(n, bool)
    for stat in FEATURES:
        key = f"feat_{stat}"
        if cols and key in results:
            ok &= np.all(np.isfinite(np.asarray(results[key], float)[:, cols]), axis=1)
    if read is not None and LYAPUNOV in read and LYAPUNOV not in index and LYAPUNOV in results:
        ok &= np.isfinite(np.asarray(results[LYAPUNOV], float))
    return ok


def feature_matrix(decl: Outcomes, system, feat, params) -> np.ndarray:
    obs, scalars = _names(system)
    cols = [parse(t, obs, scalars, "outcomes.features", boolean=False)(feat, params) for t in decl.features]
    return np.stack([np.asarray(c, float) for c in cols], axis=-1)
