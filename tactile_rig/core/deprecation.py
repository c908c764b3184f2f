"""Old public names kept working for one release, each with a :class:`DeprecationWarning` naming the new one.

Three shapes cover every rename in the package:

* :func:`renamed_kwargs` — a parameter got a name with its unit (``position`` → ``opening_m``): the
  old keyword still binds, with a warning;
* :class:`deprecated_alias` — an attribute, property or method moved (``jig.resets`` →
  ``jig.stats.resets``, ``read_n`` → ``read_force_n``): reading the old name warns and returns the new;
* :func:`deprecated_function` — a module-level function got a new name.

Moved *modules* are aliased by :mod:`tactile_rig._compat` instead.
"""

from __future__ import annotations

import functools
import operator
import warnings
from typing import Any, Callable, TypeVar

F = TypeVar("F", bound=Callable[..., Any])

#: what every warning ends with
WHEN = "the old name goes away in the next release"


def warn_renamed(old: str, new: str, *, stacklevel: int = 3) -> None:
    """Warn that ``old`` is now ``new`` (``stacklevel`` 3: the caller of the function that calls this)."""
    warnings.warn(f"{old} is deprecated: use {new} ({WHEN})", DeprecationWarning, stacklevel=stacklevel)


def renamed_kwargs(**old_to_new: str) -> Callable[[F], F]:
    """Let ``fn`` accept its parameters' old keyword names, warning once per call that uses one.

    ``@renamed_kwargs(position="opening_m")``: ``go(position=0.02)`` binds ``opening_m=0.02``;
    giving both names is a ``TypeError``, as for any parameter given twice."""

    def decorate(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            for old, new in old_to_new.items():
                if old in kwargs:
                    if new in kwargs:
                        raise TypeError(f"{fn.__qualname__}() got both {old}= and {new}=; {old} is the old "
                                        f"name of {new}")
                    warn_renamed(f"{fn.__qualname__}({old}=...)", f"{new}=")
                    kwargs[new] = kwargs.pop(old)
            return fn(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate


class deprecated_alias:  # noqa: N801 - used like ``property``
    """A class attribute that reads (and, for attributes, writes) ``target`` with a warning.

    ``target`` is a dotted path from the instance: ``resets = deprecated_alias("stats.resets")``.
    A method alias returns the bound method, so ``obj.read_n(1.0)`` calls ``obj.read_force_n(1.0)``."""

    def __init__(self, target: str) -> None:
        self.target = target
        self._get = operator.attrgetter(target)
        self.name = target

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = f"{owner.__name__}.{name}"

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        warn_renamed(self.name, f".{self.target}")
        return self._get(obj)

    def __set__(self, obj: Any, value: Any) -> None:
        warn_renamed(self.name, f".{self.target}")
        head, _, last = self.target.rpartition(".")
        setattr(operator.attrgetter(head)(obj) if head else obj, last, value)


def deprecated_function(fn: F, old_name: str) -> F:
    """``fn`` under its old module-level name ``old_name``: calling it warns and calls ``fn``."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        warn_renamed(f"{old_name}()", f"{fn.__name__}()")
        return fn(*args, **kwargs)

    wrapper.__name__ = wrapper.__qualname__ = old_name
    wrapper.__doc__ = f"Deprecated name of :func:`{fn.__name__}` ({WHEN})."
    return wrapper  # type: ignore[return-value]
