"""Fitted cycle classifiers as JSON: nested parameters and arrays, no pickle (docs/rigs.md).

:func:`to_json_tree` turns a nested structure of dicts, lists, numbers, strings, None and numpy arrays (what the
classifiers' ``to_state`` return) into JSON-able data, each array as ``{"__array__": {"dtype", "shape", "data"}}``
with its bytes little-endian and base64-encoded, so values come back bit for bit; :func:`from_json_tree` is the
inverse. Arrays of Python objects are refused (they would need a pickle).
"""

from __future__ import annotations

import base64
from typing import Any

import numpy as np

from hydrowatch.errors import DataError, ParameterError

ARRAY_KEY = "__array__"


def to_json_tree(tree: Any, where: str = "state") -> Any:
    """JSON-able form of ``tree`` (module docstring); ``where`` names the place in errors."""
    if isinstance(tree, np.ndarray):
        if tree.dtype.hasobject:
            raise ParameterError(f"{where} must be an array of numbers or text to be stored without pickle. Got dtype "
                                 f"{tree.dtype}.")
        little = tree.astype(tree.dtype.newbyteorder("<"), copy=False)
        return {ARRAY_KEY: {"dtype": little.dtype.str, "shape": list(tree.shape),
                            "data": base64.b64encode(np.ascontiguousarray(little).tobytes()).decode("ascii")}}
    if isinstance(tree, dict):
        return {str(k): to_json_tree(v, f"{where}.{k}") for k, v in tree.items()}
    if isinstance(tree, list | tuple):
        return [to_json_tree(v, f"{where}[{i}]") for i, v in enumerate(tree)]
    if isinstance(tree, np.generic):
        return tree.item()
    if tree is None or isinstance(tree, bool | int | float | str):
        return tree
    raise ParameterError(f"{where} must be made of dicts, lists, numbers, text and arrays. Got {type(tree).__name__}.")


def from_json_tree(tree: Any, source: str, where: str = "state") -> Any:
    """The structure :func:`to_json_tree` made, arrays restored; a malformed array is a :class:`DataError` naming
    ``source`` and the place."""
    if isinstance(tree, dict):
        if set(tree) == {ARRAY_KEY}:
            spec = tree[ARRAY_KEY]
            try:
                dtype = np.dtype(spec["dtype"])
                if dtype.hasobject:
                    raise ValueError("object arrays are not stored")
                data = base64.b64decode(spec["data"], validate=True)
                return np.frombuffer(data, dtype=dtype).reshape(spec["shape"]).copy()
            except (KeyError, TypeError, ValueError) as exc:
                raise DataError(f"{where} must be an array of dtype, shape and base64 data that fit. Got: {exc}.",
                                source) from None
        return {k: from_json_tree(v, source, f"{where}.{k}") for k, v in tree.items()}
    if isinstance(tree, list):
        return [from_json_tree(v, source, f"{where}[{i}]") for i, v in enumerate(tree)]
    return tree
