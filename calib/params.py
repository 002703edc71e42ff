"""Typed parameters: the pydantic base model and field types every layer's config uses.

Configs are `Params` models: unknown keys are rejected (``extra="forbid"``),
numbers are finite and never booleans, integers and booleans are strict, so a
typo or a ``true`` where a number belongs never falls back to a default.
Constructing a model with bad values raises `ParameterError` naming the
field; `model_validate` raises pydantic's ``ValidationError``, which the
application turns into ``ConfigError`` naming the file and field
(`describe`).
"""

from __future__ import annotations

import difflib
import reprlib
from typing import Annotated, Literal, get_args, get_origin

import numpy as np
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, Strict, ValidationError

from handeye.calib.errors import ParameterError


def _number(value):
    if isinstance(value, (bool, str)):
        raise ValueError(f"must be a number, got {value!r}")
    return value


def _rigid(value) -> list[list[float]]:
    from handeye.calib import transforms as tf
    from handeye.calib.errors import CalibrationError

    try:
        return tf.check_transform(np.asarray(value, dtype=float), "transform").tolist()
    except (CalibrationError, ValueError, TypeError) as e:
        raise ValueError(f"must be a 4x4 rigid transform ({e})") from None


#: A finite float (an integer is accepted; a boolean or a string is not).
Float = Annotated[float, BeforeValidator(_number), Field(allow_inf_nan=False)]
PositiveFloat = Annotated[Float, Field(gt=0)]
NonNegativeFloat = Annotated[Float, Field(ge=0)]
Fraction = Annotated[Float, Field(ge=0, le=1)]
#: An integer (a boolean, a float or a string is not).
Int = Annotated[int, Strict()]
PositiveInt = Annotated[Int, Field(gt=0)]
NonNegativeInt = Annotated[Int, Field(ge=0)]
Bool = Annotated[bool, Strict()]
Str = Annotated[str, Strict()]
NonEmptyStr = Annotated[Str, Field(min_length=1)]
Vector3 = tuple[Float, Float, Float]
Vector6 = tuple[Float, Float, Float, Float, Float, Float]
#: A 4x4 rigid transform as nested lists (TOML arrays), m.
Transform = Annotated[list[list[Float]], AfterValidator(_rigid)]


#: What a value of the wrong type should have been, by pydantic's error type: one wording for every field
#: (``must be an integer, got '30'``, as `Float`'s own ``must be a number, got 'fast'``).
_KINDS = {"int_type": "an integer", "float_type": "a number", "bool_type": "true or false", "string_type": "a string",
          "list_type": "a list", "tuple_type": "a list", "dict_type": "a table", "model_type": "a table",
          "model_attributes_type": "a table"}

#: The bounds of a number, in the same words: ``must be at most 90, got 120``.
_BOUNDS = {"greater_than": ("above", "gt"), "greater_than_equal": ("at least", "ge"), "less_than": ("below", "lt"),
           "less_than_equal": ("at most", "le")}


def _models_in(annotation) -> list[type]:
    """The `BaseModel` classes a field's annotation holds (through Optional, unions, Annotated, containers)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for a in get_args(annotation) for m in _models_in(a)]


def _keys_at(model: type | None, loc: tuple) -> set[str]:
    """The keys the table at ``loc[:-1]`` of ``model`` takes; a part that names no field (a backend's tag, a
    list index) keeps the candidates, narrowed to the models whose literal field holds it when there are."""
    candidates = [] if model is None else [model]
    for part in loc[:-1]:
        fields = [m.model_fields[part] for m in candidates if part in m.model_fields]
        if fields:
            candidates = [m for f in fields for m in _models_in(f.annotation)]
            continue
        tagged = [m for m in candidates if any(part in get_args(f.annotation) for f in m.model_fields.values()
                                               if get_origin(f.annotation) is Literal)]
        candidates = tagged or candidates
    return {name for m in candidates for name in m.model_fields}


def _details(error: ValidationError, model: type | None = None) -> list[tuple[tuple, str]]:
    """``(location, message)`` of every failed field, nested `Params` errors unrolled; ``model``: the model
    validated, whose keys an unknown key is matched against."""
    out = []
    for err in error.errors():
        inner = (err.get("ctx") or {}).get("error")
        if isinstance(inner, ParameterError) and hasattr(inner, "details"):
            out += [(err["loc"] + loc, msg) for loc, msg in inner.details]
        elif err["type"] == "extra_forbidden":
            close = difflib.get_close_matches(str(err["loc"][-1]), sorted(_keys_at(model, err["loc"])), n=1)
            out.append((err["loc"], "unknown key" + (f" (did you mean {close[0]}?)" if close else "")))
        elif err["type"] in _KINDS:
            out.append((err["loc"], f"must be {_KINDS[err['type']]}, got {reprlib.repr(err['input'])}"))
        elif err["type"] in _BOUNDS:
            word, key = _BOUNDS[err["type"]]
            bound = err["ctx"][key]
            bound = f"{bound:g}" if isinstance(bound, (int, float)) else bound
            out.append((err["loc"], f"must be {word} {bound}, got {reprlib.repr(err['input'])}"))
        elif err["type"] == "missing":
            out.append((err["loc"], "required, not given"))
        else:
            out.append((err["loc"], err["msg"].removeprefix("Value error, ")))
    return out


def describe(error: ValidationError, prefix: str = "", skip: frozenset = frozenset(), model: type | None = None) -> str:
    """One line naming each bad field: ``prefix.section.field: message; ...``.

    ``skip``: location parts to leave out (the tags pydantic puts into the
    location of a discriminated union's member, i.e. backend names);
    ``model``: the model validated, for the key an unknown one is close to.
    """
    parts = []
    for loc, msg in _details(error, model):
        where = ".".join([prefix] * bool(prefix) + [str(p) for p in loc if p not in skip])
        parts.append(f"{where}: {msg}" if where else msg)
    return "; ".join(parts)


class Params(BaseModel):
    """Base of every typed config: unknown keys rejected, field values checked on construction."""

    model_config = ConfigDict(extra="forbid")

    def __init__(self, /, **data):
        try:
            super().__init__(**data)
        except ValidationError as e:
            err = ParameterError(describe(e, type(self).__name__, model=type(self)))
            err.details = _details(e, type(self))
            raise err from None


class PinholeParams(Params):
    """Image size and pinhole intrinsics (px): the fields every camera description shares."""

    width: PositiveInt
    height: PositiveInt
    fx: PositiveFloat
    fy: PositiveFloat
    cx: Float
    cy: Float
