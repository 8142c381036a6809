"""SUREAL dataset files in and out, without executing them.

A SUREAL dataset is a Python module (or JSON object) with ``ref_videos`` (content_id,
content_name, path), ``dis_videos`` (asset_id, content_id, path, ``os``: one entry per rater,
a number or a list of repeated votes, or a dict rater -> votes) and optionally ``ref_score``.
A ``dis_video`` whose path equals its reference's path is the hidden reference. The ``.py``
form is read with :mod:`ast`: only literals, names assigned earlier, ``+`` and
``float('nan')``-style constants are accepted, so opening a dataset never runs its code.
"""

from __future__ import annotations

import ast
import json
import math
import operator
import types
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .data import InputProblem, RatingSet, rater_order
from .errors import AnalysisError

_BINOPS = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv}
_CONSTANTS = {"nan": math.nan, "NaN": math.nan, "inf": math.inf, "None": None,
              "True": True, "False": False}

# Limits for reading a dataset file: a file is plain data, never a program that allocates.
MAX_FILE_BYTES = 256 * 1024 * 1024
MAX_DEPTH = 64  # nesting of lists/dicts (a dataset needs 4)
MAX_ELEMENTS = 20_000_000  # list items, dict entries and string characters created


class _Budget:
    """Counts what evaluating a file creates and refuses to go past the limits."""

    def __init__(self, where: str) -> None:
        self.where = where
        self.left = MAX_ELEMENTS

    def take(self, n: int) -> None:
        self.left -= max(int(n), 0)
        if self.left < 0:
            raise AnalysisError(f"{self.where}: the dataset would create more than "
                                f"{MAX_ELEMENTS:,} values; refusing to read it")


def _size(value: Any) -> int:
    return len(value) if isinstance(value, (list, tuple, str, bytes, dict)) else 1


def _binop(op: ast.operator, left: Any, right: Any, budget: _Budget, where: str) -> Any:
    if isinstance(op, ast.Mult):
        seq, times = (left, right) if isinstance(left, (list, tuple, str)) else (right, left)
        if isinstance(seq, (list, tuple, str)):
            if isinstance(times, bool) or not isinstance(times, int):
                raise AnalysisError(f"{where}: a sequence can only be repeated a whole number "
                                    "of times")
            budget.take(len(seq) * max(times, 0))
    elif isinstance(op, ast.Add) and isinstance(left, (list, tuple, str)):
        budget.take(_size(left) + _size(right))
    try:
        return _BINOPS[type(op)](left, right)
    except (TypeError, ZeroDivisionError, OverflowError, ValueError) as exc:
        raise AnalysisError(f"{where}: {exc}") from None


def _evaluate(node: ast.AST, env: dict[str, Any], where: str, budget: _Budget,
              depth: int = 0) -> Any:
    """Evaluate a plain-data expression; anything else is refused."""
    if depth > MAX_DEPTH:
        raise AnalysisError(f"{where}: data nested deeper than {MAX_DEPTH} levels")
    deeper = depth + 1
    if isinstance(node, ast.Constant):
        if isinstance(node.value, (str, bytes)):
            budget.take(len(node.value))
        return node.value
    if isinstance(node, (ast.List, ast.Tuple)):
        budget.take(len(node.elts))
        items = [_evaluate(n, env, where, budget, deeper) for n in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        if any(k is None for k in node.keys):
            raise AnalysisError(f"{where}: '**' in a dict is not plain data")
        budget.take(len(node.keys))
        out = {}
        for k, v in zip(node.keys, node.values, strict=True):
            key = _evaluate(k, env, where, budget, deeper)
            try:
                out[key] = _evaluate(v, env, where, budget, deeper)
            except TypeError:
                raise AnalysisError(f"{where}: dict key {key!r} is not a plain value "
                                    "(number or text)") from None
        return out
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        if node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        raise AnalysisError(f"{where}: name {node.id!r} is not defined earlier in the file")
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        left = _evaluate(node.left, env, where, budget, deeper)
        right = _evaluate(node.right, env, where, budget, deeper)
        return _binop(node.op, left, right, budget, where)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _evaluate(node.operand, env, where, budget, deeper)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise AnalysisError(f"{where}: unary {'-' if isinstance(node.op, ast.USub) else '+'}"
                                f" applies to numbers only, not to {type(value).__name__}")
        return -value if isinstance(node.op, ast.USub) else value
    if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id == "float" and len(node.args) == 1 and not node.keywords):
        arg = _evaluate(node.args[0], env, where, budget, deeper)
        if isinstance(arg, str) and arg.strip().lower() in ("nan", "inf", "-inf"):
            return float(arg)
    if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
            and node.value.id in ("np", "numpy", "math") and node.attr in ("nan", "NaN", "inf")):
        return math.nan if node.attr != "inf" else math.inf
    raise AnalysisError(
        f"{where}: expression {ast.unparse(node)[:60]!r} is not plain data; SUREAL dataset "
        "files are read without running them, so they may hold only literals"
    )


def parse_sureal_py(text: str, *, source: str = "<dataset>") -> dict[str, Any]:
    """The top-level assignments of a SUREAL ``.py`` dataset, evaluated as plain data."""
    try:
        tree = ast.parse(text, filename=source)
    except SyntaxError as exc:
        raise AnalysisError(f"{source} is not valid Python ({exc.msg}, line {exc.lineno})") \
            from None
    except (RecursionError, MemoryError, ValueError) as exc:
        raise AnalysisError(f"{source} is too deeply nested or too large to read "
                            f"({type(exc).__name__})") from None
    env: dict[str, Any] = {}
    budget = _Budget(source)
    for stmt in tree.body:
        if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Constant):
            continue  # docstring
        if isinstance(stmt, (ast.Import, ast.ImportFrom)):
            continue  # e.g. "import numpy as np" for np.nan; nothing is imported
        if isinstance(stmt, ast.Assign) and all(isinstance(t, ast.Name) for t in stmt.targets):
            try:
                value = _evaluate(stmt.value, env, f"{source}:{stmt.lineno}", budget)
            except RecursionError:
                raise AnalysisError(f"{source}:{stmt.lineno}: data nested too deeply") \
                    from None
            for target in stmt.targets:
                env[target.id] = value
            continue
        raise AnalysisError(
            f"{source}:{stmt.lineno}: only plain assignments are allowed in a SUREAL dataset "
            "file (it is parsed, not executed)"
        )
    return env


def _depth_ok(value: Any, where: str) -> None:
    """Walk JSON data without recursion; refuse nesting deeper than :data:`MAX_DEPTH`."""
    stack = [(value, 0)]
    while stack:
        item, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise AnalysisError(f"{where}: data nested deeper than {MAX_DEPTH} levels")
        if isinstance(item, dict):
            stack += [(v, depth + 1) for v in item.values()]
        elif isinstance(item, list):
            stack += [(v, depth + 1) for v in item]


def read_sureal_dataset(path: str | Path) -> dict[str, Any]:
    """The dataset of a SUREAL ``.py`` or ``.json`` file as a dict."""
    path = Path(path)
    if path.suffix not in (".py", ".json"):
        raise AnalysisError(f"SUREAL dataset file {path} must end in .py or .json")
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            raise AnalysisError(f"SUREAL dataset file {path} is {size / 1e6:.0f} MB; more than "
                                f"{MAX_FILE_BYTES // 1024**2} MB is not read")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise AnalysisError(f"SUREAL dataset file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise AnalysisError(f"cannot read SUREAL dataset file {path} ({exc})") from None
    if path.suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise AnalysisError(f"{path} is not valid JSON ({exc})") from None
        except RecursionError:
            raise AnalysisError(f"{path}: data nested too deeply") from None
        _depth_ok(data, str(path))
        if not isinstance(data, dict):
            raise AnalysisError(f"{path}: a SUREAL JSON dataset must be an object")
    else:
        data = parse_sureal_py(text, source=str(path))
    for key in ("ref_videos", "dis_videos"):
        if not isinstance(data.get(key), list) or not data[key]:
            raise AnalysisError(f"{path}: a SUREAL dataset needs a non-empty list {key!r}")
    return data


def _vote(v: Any) -> float:
    """One vote as a float; None is a gap; anything but a real number raises ValueError."""
    if v is None:
        return float("nan")
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f"vote {v!r} is not a number")
    return float(v)


def _votes(value: Any) -> list[float]:
    """A rater's votes: a number or a flat list of numbers (repetitions)."""
    if isinstance(value, (list, tuple)):
        return [_vote(v) for v in value]
    return [_vote(value)]


def _hashable_id(value: Any) -> bool:
    return isinstance(value, (int, str)) and not isinstance(value, bool)


def _stem(path: Any, fallback: str) -> str:
    name = Path(str(path)).stem if path else ""
    return name or fallback


def ratings_from_sureal(data: dict[str, Any], *, source: str = "<dataset>") -> RatingSet:
    """A :class:`RatingSet` from a SUREAL dataset dict, keeping its stimulus and rater order.

    Votes that are not numbers become gaps and are reported; the scale is ACR 1..5 when the
    data fit it (``ref_score`` 5), otherwise the observed range up to ``ref_score``.
    Long on purpose: the dataset's fields are checked in the order SUREAL defines them, each
    with its own message, before one matrix is built from them.
    """
    problems: list[InputProblem] = []
    refs: dict[Any, dict[str, Any]] = {}
    for i, ref in enumerate(data["ref_videos"]):
        if not isinstance(ref, dict) or "content_id" not in ref:
            raise AnalysisError(f"{source}: ref_videos[{i}] lacks a content_id")
        if not _hashable_id(ref["content_id"]):
            raise AnalysisError(f"{source}: ref_videos[{i}] content_id "
                                f"{str(ref['content_id'])[:40]!r} is not a number or text")
        refs[ref["content_id"]] = ref
    ref_ids = {cid: str(ref.get("content_name") or f"content{cid}") for cid, ref in refs.items()}
    if len(set(ref_ids.values())) != len(ref_ids):
        ref_ids = {cid: f"{name}_{cid}" for cid, name in ref_ids.items()}

    dis = data["dis_videos"]
    first_os = dis[0].get("os") if isinstance(dis[0], dict) else None
    if isinstance(first_os, dict):
        raters = rater_order(k for d in dis if isinstance(d, dict)
                             and isinstance(d.get("os"), dict) for k in d["os"])
    elif isinstance(first_os, (list, tuple)):
        raters = [str(i) for i in range(len(first_os))]
    else:
        raise AnalysisError(f"{source}: dis_videos[0] has no 'os' list or dict of votes")

    ids, rows, votes = [], [], []
    for i, d in enumerate(dis):
        if not isinstance(d, dict) or not _hashable_id(d.get("content_id")) or \
                d.get("content_id") not in refs or \
                not isinstance(d.get("os"), (list, tuple, dict)):
            problems.append(InputProblem(source, i, "dis_video without a known content_id or "
                                         "'os' votes; left out"))
            continue
        cid = d["content_id"]
        is_ref = d.get("path") is not None and d.get("path") == refs[cid].get("path")
        sid = ref_ids[cid] if is_ref else _stem(d.get("path"), f"asset{d.get('asset_id', i)}")
        if sid in ids:
            sid = f"{sid}_asset{d.get('asset_id', i)}"
        os_ = d["os"]
        if not isinstance(os_, dict) and len(os_) != len(raters):
            problems.append(InputProblem(source, i, f"{len(os_)} raters where "
                                         f"{len(raters)} were expected; left out"))
            continue
        raw = [os_.get(r, os_.get(_maybe_int(r), [])) for r in raters] \
            if isinstance(os_, dict) else list(os_)
        per_rater = []
        for rater, value in zip(raters, raw, strict=True):
            try:
                per_rater.append(_votes(value))
            except ValueError as exc:
                problems.append(InputProblem(source, i, f"rater {rater}: {exc} (votes must be "
                                             "numbers or lists of numbers); left out"))
                per_rater.append([])
        ids.append(sid)
        rows.append({"reference": ref_ids[cid], "scene": ref_ids[cid],
                     "method": "reference" if is_ref else "distorted", "level": None,
                     "is_hidden_reference": is_ref})
        votes.append(per_rater)
    if not ids:
        raise AnalysisError(f"{source}: no usable dis_videos")
    if not raters:
        raise AnalysisError(f"{source}: no raters in the 'os' votes")
    n_rep = max(1, max(len(v) for per in votes for v in per))
    scores = np.full((len(ids), len(raters), n_rep), np.nan)
    for e, per in enumerate(votes):
        for s, v in enumerate(per):
            scores[e, s, : len(v)] = v
    bad = np.isinf(scores)
    if bad.any():
        problems.append(InputProblem(source, None, f"{int(bad.sum())} infinite vote(s) "
                                     "left out"))
        scores[bad] = np.nan
    if not np.isfinite(scores).any():
        raise AnalysisError(f"{source}: no numeric votes")
    ref_score = data.get("ref_score")
    if ref_score is not None and (isinstance(ref_score, bool)
                                  or not isinstance(ref_score, (int, float))
                                  or not math.isfinite(ref_score)):
        raise AnalysisError(f"{source}: ref_score {str(ref_score)[:40]!r} is not a finite "
                            "number (SUREAL's DMOS anchor, e.g. 5 on an ACR scale)")
    lo, hi = float(np.nanmin(scores)), float(np.nanmax(scores))
    if ref_score is None:
        ref_score = 5.0 if lo >= 1 and hi <= 5 else hi
    scale_min = 1.0 if lo >= 1 and float(ref_score) == 5.0 else min(lo, 0.0)
    table = pd.DataFrame(rows, index=pd.Index(ids, name="stimulus"))
    table["level"] = pd.array(table["level"], dtype="Int64")
    return RatingSet(
        stimuli=table, raters=raters, scores=scores, scale_min=scale_min,
        scale_max=max(float(ref_score), hi), ref_score=float(ref_score),
        study=str(data.get("dataset_name", Path(source).stem)), source=source,
        problems=problems,
    )


def _maybe_int(key: str) -> Any:
    try:
        return int(key)
    except ValueError:
        return key


def load_sureal(path: str | Path) -> RatingSet:
    """Read a SUREAL dataset file (``.py`` parsed, never executed; or ``.json``)."""
    return ratings_from_sureal(read_sureal_dataset(path), source=str(path))


def sureal_dataset(rs: RatingSet, *, with_gaps_as_nan: bool = True) -> dict[str, Any]:
    """The rating set as a SUREAL dataset dict (repetitions as a list per rater).

    Stimuli whose reference has no hidden-reference stimulus get a reference entry of their
    own (with a path no dis_video shares), so SUREAL's DMOS models know it is missing.
    """
    refs = list(dict.fromkeys(rs.stimuli["reference"]))
    cid = {ref: i for i, ref in enumerate(refs)}
    ref_videos = [{"content_id": cid[r], "content_name": str(r), "path": f"{r}"} for r in refs]
    dis_videos = []
    for e, (sid, row) in enumerate(rs.stimuli.iterrows()):
        os_ = []
        for s in range(rs.n_raters):
            v = rs.scores[e, s]
            v = v[np.isfinite(v)]
            if v.size == 0:
                os_.append([math.nan] if with_gaps_as_nan else [])
            else:
                os_.append([float(x) for x in v])
        dis_videos.append({
            "asset_id": e, "content_id": cid[row["reference"]],
            "path": str(row["reference"]) if row["is_hidden_reference"] else str(sid),
            "os": os_,
        })
    return {"dataset_name": rs.study, "ref_score": rs.ref_score,
            "ref_videos": ref_videos, "dis_videos": dis_videos}


def sureal_namespace(rs: RatingSet) -> types.SimpleNamespace:
    """The object SUREAL's dataset readers expect (attributes instead of module globals)."""
    return types.SimpleNamespace(**sureal_dataset(rs))


def write_sureal_json(rs: RatingSet, path: str | Path) -> Path:
    """Write the SUREAL JSON dataset, ``os`` as a dict rater -> list of repeated votes.

    The dict form lets a rater skip a stimulus (SUREAL reads absent raters as gaps), which the
    plain list form cannot express in strict JSON.
    """
    data = sureal_dataset(rs, with_gaps_as_nan=False)
    for d in data["dis_videos"]:
        d["os"] = {r: v for r, v in zip(rs.raters, d["os"], strict=True) if v}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, allow_nan=False), encoding="utf-8")
    return path
