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

from typing import Annotated

import numpy as np
from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, Strict, ValidationError

from calib.errors import ParameterError


def _number(value):
    if isinstance(value, (bool, str)):
        raise ValueError(f"must be a number, got {value!r}")
    return value


def _rigid(value) -> list[list[float]]:
    from calib import transforms as tf
    from calib.errors import CalibrationError

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


def _details(error: ValidationError) -> list[tuple[tuple, str]]:
    """``(location, message)`` of every failed field, nested `Params` errors unrolled."""
    out = []
    for err in error.errors():
        inner = (err.get("ctx") or {}).get("error")
        if isinstance(inner, ParameterError) and hasattr(inner, "details"):
            out += [(err["loc"] + loc, msg) for loc, msg in inner.details]
        elif err["type"] == "extra_forbidden":
            out.append((err["loc"], "unknown key"))
        else:
            out.append((err["loc"], err["msg"].removeprefix("Value error, ")))
    return out


def describe(error: ValidationError, prefix: str = "", skip: frozenset = frozenset()) -> str:
    """One line naming each bad field: ``prefix.section.field: message; ...``.

    ``skip``: location parts to leave out (the tags pydantic puts into the
    location of a discriminated union's member, i.e. backend names).
    """
    parts = []
    for loc, msg in _details(error):
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
            err = ParameterError(describe(e, type(self).__name__))
            err.details = _details(e)
            raise err from None


class PinholeParams(Params):
    """Image size and pinhole intrinsics (px): the fields every camera description shares."""

    width: PositiveInt
    height: PositiveInt
    fx: PositiveFloat
    fy: PositiveFloat
    cx: Float
    cy: Float
