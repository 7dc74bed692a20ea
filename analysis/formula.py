"""lme4 model formulas: parse ``y ~ fixed + (expr | group)`` and build the model's matrices.

The fixed part goes through formulaic (a maintained Wilkinson-formula library with R's
semantics: ``*``, ``:``, ``-1``, ``I()``, ``C(x, contr.sum)``); factors get R's default
treatment contrasts, or sum contrasts with ``C(x, contr.sum)`` (the same text works in R), and
the coefficients R's names (``illuminationB``, ``C(a, contr.sum)1``, ``gloss:depth``).

The random part follows lme4's ``findbars`` / ``mkReTrms`` (Bates et al. 2015, section 2):

- ``(a + b | g)``: correlated intercept and slopes per level of ``g``;
- ``(a + b || g)``: uncorrelated, expanded to ``(1 | g) + (0 + a | g) + (0 + b | g)``;
- ``(1 | g1/g2)``: nested, expanded to ``(1 | g2:g1) + (1 | g1)``;
- ``(1 | g1:g2)``: a grouping factor of the combinations;
- several terms are crossed or nested as the data make them.

Terms are then ordered by decreasing number of levels (lme4's ``reorder.terms``), which fixes the
order of theta.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd
import scipy.sparse as sp

__all__ = ["FixedPart", "FormulaError", "LmmError", "ModelSpec", "RandomTerm", "build_model",
           "split_formula"]


class LmmError(ValueError):
    """Bad input to a mixed model (missing columns, too few levels, non-finite values)."""


class FormulaError(LmmError):
    """A formula that cannot be parsed or does not fit the data."""


@dataclass(frozen=True)
class RandomTerm:
    """One random-effect term ``(expr | group)`` after expansion.

    Attributes
    ----------
    expr : str
        The left-hand side, e.g. ``"1 + gloss + depth"`` or ``"0 + gloss"``.
    group : str
        The grouping factor, e.g. ``"participant"`` or ``"cask:batch"``.
    """

    expr: str
    group: str


def _split_top(text: str, sep: str) -> list[str]:
    """Split on ``sep`` outside parentheses."""
    out, depth, cur = [], 0, []
    i = 0
    while i < len(text):
        ch = text[i]
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
            if depth < 0:
                raise FormulaError(f"unbalanced ')' in {text!r}")
        if depth == 0 and text.startswith(sep, i):
            out.append("".join(cur))
            cur = []
            i += len(sep)
            continue
        cur.append(ch)
        i += 1
    if depth != 0:
        raise FormulaError(f"unbalanced '(' in {text!r}")
    out.append("".join(cur))
    return out


def _expand_slash(group: str) -> list[str]:
    """lme4's ``expandSlash``: ``a/b/c`` -> ``c:b:a``, ``b:a``, ``a``."""
    parts = [p.strip() for p in group.split("/")]
    if any(not p for p in parts):
        raise FormulaError(f"empty grouping factor in {group!r}")
    return [":".join(reversed(parts[: k + 1])) for k in range(len(parts) - 1, -1, -1)]


def _expand_bar(inner: str) -> list[RandomTerm]:
    double = "||" in inner
    pieces = _split_top(inner, "||" if double else "|")
    if len(pieces) != 2:
        raise FormulaError(f"random-effect term ({inner}) needs one '|' or '||': (expr | group)")
    expr, group = pieces[0].strip(), pieces[1].strip()
    if not expr or not group:
        raise FormulaError(f"random-effect term ({inner}) needs both sides: (expr | group)")
    groups = _expand_slash(group)
    if not double:
        return [RandomTerm(expr, g) for g in groups]
    # lme4's expandDoubleVerts: one term for the intercept (unless removed) and one per variable.
    parts = [p.strip() for p in _split_top(expr.replace("-", "+-"), "+") if p.strip()]
    no_intercept = any(p in ("0", "-1") for p in parts)
    variables = [p for p in parts if p not in ("0", "1", "-1", "+1")]
    exprs = ([] if no_intercept else ["1"]) + [f"0 + {v}" for v in variables]
    return [RandomTerm(e, g) for g in groups for e in exprs]


def split_formula(formula: str) -> tuple[str, str, tuple[RandomTerm, ...]]:
    """Split an lme4 formula into response, fixed right-hand side and random terms.

    Parameters
    ----------
    formula : str
        E.g. ``"y ~ gloss * depth + (1 + gloss + depth | participant) + (1 | stimulus_id)"``.

    Returns
    -------
    response : str
    fixed : str
        The fixed part (``"1"`` if only random terms are given).
    random : tuple of RandomTerm
        After expanding ``||`` and ``/``, in the order written.

    Raises
    ------
    FormulaError
        No ``~``, no response, unbalanced parentheses or no random-effect term.
    """
    if formula.count("~") != 1:
        raise FormulaError(f"formula {formula!r} needs exactly one '~': 'response ~ terms'")
    lhs, rhs = (s.strip() for s in formula.split("~"))
    if not lhs:
        raise FormulaError(f"formula {formula!r} has no response left of '~'")
    fixed, random = [], []
    for piece in _split_top(rhs, "+"):
        p = piece.strip()
        if not p:
            raise FormulaError(f"empty term in {formula!r} (two '+' in a row?)")
        m = re.fullmatch(r"\((.*)\)", p, flags=re.DOTALL)
        if m and "|" in m.group(1) and len(_split_top(m.group(1), "|")) > 1:
            random.extend(_expand_bar(m.group(1)))
        elif "|" in p:  # a random term with text before or after its parentheses
            raise FormulaError(f"term {p!r} of {formula!r} is not one random-effect term: write "
                               "it alone in parentheses, (expr | group), and join terms with "
                               "'+'")
        else:
            fixed.append(p)
    seen = [t for k, t in enumerate(random) if t in random[:k]]
    if seen:
        raise FormulaError(f"random term ({seen[0].expr} | {seen[0].group}) is given twice in "
                           f"{formula!r}: its two variances could not be told apart; give it once")
    if not random:
        raise FormulaError(
            f"formula {formula!r} has no random-effect term such as (1 | participant); "
            "a mixed model needs at least one (use ordinary least squares otherwise)")
    return lhs, " + ".join(fixed) if fixed else "1", tuple(random)


def _r_name(column: str, contrasts: dict) -> str:
    """R's coefficient name for a formulaic column name."""
    if column == "Intercept":
        return "(Intercept)"
    out = []
    for piece in column.split(":"):
        m = re.fullmatch(r"(.*)\[([TS])\.(.*)\]", piece)
        if m is None:
            out.append(piece)
            continue
        factor, kind, level = m.groups()
        if kind == "T":
            out.append(f"{factor}{level}")
        else:
            levels = [str(v) for v in contrasts[factor]]
            out.append(f"{factor}{levels.index(level) + 1}")
    return ":".join(out)


@dataclass(frozen=True)
class FixedPart:
    """The fixed-effect design.

    Attributes
    ----------
    X : ndarray, shape (n, p)
    names : tuple of str
        R's coefficient names.
    terms : tuple of str
        Term labels (``"gloss"``, ``"gloss:depth"``), intercept excluded.
    assign : tuple of int
        Per column, the index into ``terms`` (-1 for the intercept), as R's ``assign``.
    term_factors : tuple of frozenset
        Per term, the variables it is made of (for car's Type II relatives).
    """

    X: np.ndarray
    names: tuple
    terms: tuple
    assign: tuple
    term_factors: tuple


@dataclass(frozen=True)
class ModelSpec:
    """Everything a fit needs, built from a formula and a data frame.

    Attributes
    ----------
    formula, response : str
    y : ndarray, shape (n,)
    fixed : FixedPart
    re_groups : tuple of str
        Grouping factor of each random term, lme4's order.
    re_names : tuple of tuple of str
        Coefficient names of each random term (``"(Intercept)"``, ``"gloss"``).
    re_levels : tuple of ndarray
        Level labels of each term's grouping factor.
    re_index : tuple of ndarray of int
        Per term, each row's level.
    re_values : tuple of ndarray
        Per term, shape (n, q_k): each row's values of the term's columns.
    n_dropped : int
        Rows left out for missing values (lme4's ``na.omit``).
    """

    formula: str
    response: str
    y: np.ndarray
    fixed: FixedPart
    re_groups: tuple
    re_names: tuple
    re_levels: tuple
    re_index: tuple
    re_values: tuple
    n_dropped: int

    @property
    def n(self) -> int:
        return int(self.y.size)

    @property
    def q_sizes(self) -> tuple:
        """Coefficients per level of each term."""
        return tuple(v.shape[1] for v in self.re_values)

    def Z(self) -> sp.csc_matrix:
        """The random-effect design, sparse, columns level-major within each term (lme4's Zt')."""
        blocks = []
        for idx, vals, levels in zip(self.re_index, self.re_values, self.re_levels):
            n, q = vals.shape
            rows = np.repeat(np.arange(n), q)
            cols = (idx[:, None] * q + np.arange(q)[None, :]).ravel()
            blocks.append(sp.csc_matrix((vals.ravel(), (rows, cols)), shape=(n, levels.size * q)))
        return sp.hstack(blocks, format="csc")


def _variables(text: str, data: pd.DataFrame) -> list[str]:
    """Column names of ``data`` that appear as identifiers in ``text``."""
    names = set(re.findall(r"[A-Za-z_.][A-Za-z0-9_.]*", text))
    return [c for c in data.columns if c in names]


#: Functions formulaic (and R) accept inside a formula's fixed or random part.
_FUNCTIONS = ("C", "I", "Q", "log", "exp", "sqrt", "center", "scale", "poly", "bs", "np.log",
              "np.exp", "np.sqrt", "contr.sum", "contr.treatment", "contr.helmert", "contr.poly")
#: R formula functions this lmer does not fit, and what to do instead.
_UNSUPPORTED = {
    "offset": "subtract the offset from the response in the data (a new column) and name that "
              "column left of '~'",
    "s": "smooth terms belong to GAMs (mgcv), not lmer: use poly(x, 2) or bs(x, df=4)",
    "te": "smooth terms belong to GAMs (mgcv), not lmer: use poly(x, 2) or bs(x, df=4)",
    "cbind": "a two-column response is for binomial glmer; this fits a Gaussian lmer to one "
             "numeric column",
    "factor": "write C(x) (the same; C(x, contr.sum) for sum contrasts)",
}


def _unsupported_call(text: str, where: str) -> None:
    """Refuse a function call the fits do not support, naming what is supported."""
    for name in re.findall(r"(?<![\w.])([A-Za-z_.][A-Za-z0-9_.]*)\s*\(", text):
        if name in _FUNCTIONS:
            continue
        why = _UNSUPPORTED.get(name, "not a function of these formulas")
        raise FormulaError(f"{where}: {name}() is unsupported: {why}. Supported: column names, "
                           "a * b, a:b, a + b, -1 and "
                           f"{', '.join(f + '()' for f in _FUNCTIONS if '.' not in f)}")


def _check_columns(text: str, data: pd.DataFrame, what: str) -> None:
    _unsupported_call(text, what)
    if re.search(r"(?<![\w.])\.(?![\w.])", text):
        raise FormulaError(f"{what}: '.' (every other column) is unsupported: name the "
                           "predictors, e.g. 'y ~ a + b + (1 | g)'")
    known = set(map(str, data.columns)) | set(_FUNCTIONS)
    text = re.sub(r"'[^']*'|\"[^\"]*\"", "", text)
    for name in re.findall(r"(?<![\w.])([A-Za-z_.][A-Za-z0-9_.]*)", text):
        if name not in known and not name.isdigit():
            raise FormulaError(
                f"{what} names {name!r}, which is not a column of the data; the columns are "
                f"{sorted(map(str, data.columns))}")


def _design(text: str, data: pd.DataFrame):
    import formulaic

    try:
        mm = formulaic.model_matrix(text, data, na_action="raise")
    except Exception as exc:  # formulaic raises many types; name the formula in one error.
        raise FormulaError(f"cannot build the design of {text!r}: {exc}") from exc
    return mm


def _grouping(group: str, data: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    cols = [c.strip() for c in group.split(":")]
    for c in cols:
        if c not in data.columns:
            raise FormulaError(
                f"grouping factor {c!r} is not a column of the data; the columns are "
                f"{sorted(map(str, data.columns))}")
    labels = data[cols[0]].astype(str).to_numpy()
    for c in cols[1:]:
        labels = np.char.add(np.char.add(data[c].astype(str).to_numpy().astype(str), ":"),
                             labels.astype(str))
    levels, index = np.unique(labels.astype(str), return_inverse=True)
    return levels, index


def build_model(formula: str, data: pd.DataFrame) -> ModelSpec:
    """Parse ``formula`` and build X, y and the random-effect structure from ``data``.

    Rows with a missing value in any variable of the formula are left out (lme4's default
    ``na.omit``) and counted.

    Parameters
    ----------
    formula : str
        An lme4 formula, see the module docstring.
    data : DataFrame

    Returns
    -------
    ModelSpec

    Raises
    ------
    FormulaError
        A variable not in the data, a non-numeric response, a grouping factor with fewer than
        two levels, or as many random effects per level as observations.
    """
    response, fixed_text, random = split_formula(formula)
    if response not in data.columns and "(" in response:
        _unsupported_call(response, f"the response {response!r}")
        raise FormulaError(f"the response {response!r} is a transformed column, which is "
                           "unsupported: add the transformed values to the data as a column "
                           "(e.g. log_y) and name that column left of '~'")
    if response not in data.columns:
        raise FormulaError(f"response {response!r} is not a column of the data; the columns are "
                           f"{sorted(map(str, data.columns))}")
    _check_columns(fixed_text, data, "the fixed part")
    for term in random:
        _check_columns(term.expr, data, f"random term ({term.expr} | {term.group})")
    used = {response}
    used.update(_variables(fixed_text, data))
    for term in random:
        used.update(_variables(term.expr, data))
        used.update(c.strip() for c in term.group.split(":"))
    used = [c for c in data.columns if c in used]
    keep = data[used].notna().all(axis=1).to_numpy()
    frame = data.loc[keep, used].reset_index(drop=True)
    if frame.empty:
        raise FormulaError(f"no complete rows for {used}; every row has a missing value")
    y = pd.to_numeric(frame[response], errors="coerce").to_numpy(float)
    if not np.isfinite(y).all():
        bad = int(np.flatnonzero(~np.isfinite(y))[0])
        row = int(np.flatnonzero(keep)[bad])
        raise FormulaError(
            f"response {response!r} must be numeric and finite; data row {row + 1} (line "
            f"{row + 2} of a CSV with a header) has {frame[response].iloc[bad]!r}: fix or remove "
            "that row")
    mm = _design(fixed_text, frame)
    spec = mm.model_spec
    contrasts = {str(k): v.levels for k, v in spec.factor_contrasts.items()}
    names, assign, terms, factors = [], [], [], []
    for term, sl in spec.term_slices.items():
        label = str(term)
        if label == "1":
            k = -1
        else:
            terms.append(label)
            factors.append(frozenset(str(f) for f in term.factors))
            k = len(terms) - 1
        for col in mm.columns[sl]:
            names.append(_r_name(col, contrasts))
            assign.append(k)
    X = np.asarray(mm, dtype=float)
    if np.linalg.matrix_rank(X) < X.shape[1]:
        raise FormulaError(
            f"the fixed effects of {fixed_text!r} are not estimable from these data (the "
            "design is rank deficient: a factor level combination is missing or a predictor "
            "is constant); drop or merge terms")
    fixed = FixedPart(X=X, names=tuple(names), terms=tuple(terms), assign=tuple(assign),
                      term_factors=tuple(factors))
    built = []
    for term in random:
        zmm = _design(term.expr, frame)
        znames = tuple(_r_name(c, {str(k): v.levels for k, v in
                                   zmm.model_spec.factor_contrasts.items()})
                       for c in zmm.columns)
        levels, index = _grouping(term.group, frame)
        if levels.size < 2:
            raise FormulaError(
                f"grouping factor {term.group!r} has one level ({levels[0]!r}); a random "
                "effect needs at least two (drop the term or fit a fixed effect)")
        vals = np.asarray(zmm, dtype=float)
        if levels.size >= y.size:
            raise FormulaError(
                f"grouping factor {term.group!r} has {levels.size} levels for {y.size} "
                "observations; a random effect needs fewer levels than observations")
        built.append((term.group, znames, levels, index, vals))
    # lme4's mkReTrms: if any term has more levels than the one before it, order by decreasing
    # number of levels (ties in reverse order of appearance, as rev(order(nl))).
    nl = [b[2].size for b in built]
    if any(b > a for a, b in itertools.pairwise(nl)):
        order = list(reversed(np.argsort(nl, kind="stable").tolist()))
        built = [built[k] for k in order]
    return ModelSpec(
        formula=formula, response=response, y=y, fixed=fixed,
        re_groups=tuple(b[0] for b in built), re_names=tuple(b[1] for b in built),
        re_levels=tuple(b[2] for b in built), re_index=tuple(b[3] for b in built),
        re_values=tuple(b[4] for b in built), n_dropped=int((~keep).sum()),
    )
