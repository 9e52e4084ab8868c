"""Old names kept working for one release, with a ``DeprecationWarning`` (issue 30: identifiers
took the American spelling, ``centre_mm`` -> ``center_mm``, ``colour`` -> ``color``, ...).

- ``renamed_kwargs({"old": "new"})`` on a function: a call with the old keyword passes it under
  the new one. On a class: its constructor's keywords, and reading an old attribute name (a
  renamed field or method) returns the new one.
- ``module_getattr(globals(), {"old": "new"})``: a module's ``__getattr__`` that serves a renamed
  function, class or constant under its old name (``from module import old`` too).

Old names are written as strings so that the renaming script, which rewrites identifiers only,
leaves them as they are when it is run again.
"""

from __future__ import annotations

import functools
import inspect
import warnings
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def _warn(where: str, old: str, new: str) -> None:
    warnings.warn(f"{where}: '{old}' is deprecated, use '{new}' (the old name goes in the next release)",
                  DeprecationWarning, stacklevel=3)


def _renamed_call(func: Callable, renames: Mapping[str, str], where: str) -> Callable:
    @functools.wraps(func)
    def call(*args: Any, **kwargs: Any) -> Any:
        for old in renames.keys() & kwargs.keys():
            new = renames[old]
            if new in kwargs:
                raise TypeError(f"{where}() got both '{old}' and its new name '{new}'")
            _warn(where, old, new)
            kwargs[new] = kwargs.pop(old)
        return func(*args, **kwargs)
    return call


def _old_attribute(old: str, new: str, where: str) -> property:
    def read(self: Any) -> Any:
        _warn(where, old, new)
        return getattr(self, new)
    return property(read, doc=f"Deprecated name of ``{new}``.")


def renamed_kwargs(renames: Mapping[str, str]) -> Callable[[F], F]:
    """Decorator: the old keyword names (keys) still work as the new ones (values), warning.
    On a class (put it above ``@dataclass``) the constructor is wrapped (when a new name is one of
    its parameters) and each old name is also a read-only attribute that warns and returns the
    new one (a field, or a bound method)."""
    renames = dict(renames)

    def wrap(obj: F) -> F:
        if isinstance(obj, type):
            cls: type = obj
            where = cls.__qualname__
            if set(renames.values()) & set(inspect.signature(cls).parameters):
                cls.__init__ = _renamed_call(cls.__init__, renames, where)   # type: ignore[misc]
            for old, new in renames.items():
                setattr(cls, old, _old_attribute(old, new, where))
            return obj
        return _renamed_call(obj, renames, obj.__qualname__)                  # type: ignore[return-value]
    return wrap


def module_getattr(namespace: dict[str, Any], renames: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` (PEP 562) serving each old name (keys) as its new one (values) of
    the module ``namespace`` (its ``globals()``), warning."""
    renames = dict(renames)
    module = namespace["__name__"]

    def __getattr__(name: str) -> Any:
        if name in renames:
            _warn(module, name, renames[name])
            return namespace[renames[name]]
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    return __getattr__
