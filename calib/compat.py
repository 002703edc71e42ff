"""What Python 3.10 (ROS 2 Humble's) lacks of the standard library that handeye uses, in one place."""

import sys
from enum import Enum

if sys.version_info >= (3, 11):
    from enum import StrEnum
else:
    class StrEnum(str, Enum):
        """`enum.StrEnum` of Python 3.11: a member is its string value (``str(m)``, ``f"{m}"``, ``m == "x"``)."""

        def __str__(self) -> str:
            return str(self.value)

        def __format__(self, spec: str) -> str:
            return format(str(self.value), spec)

__all__ = ["StrEnum"]
