"""The registry of arbitration modes: every mode is one plug-in module and one line here.

A mode is one small module of this package that defines `SPEC`, a `base.ModeSpec` (its name,
its alpha rule, its own parameters and their default search space, its own filter state),
and one entry of `BUILTIN` below. Everything that lists modes (the `Mode` type, the viewer's
dropdown, the study's modes, replay's `--modes`, `--mode`, tune's spaces, the configuration's
mode parameters) reads this registry, so adding a mode edits nothing else; `register` adds
one from anywhere (a test file does), `unregister` removes it.

`Mode` is the type of a registered mode: a string (its name, `Mode.DS == "DS"`), one
instance per mode (`Mode.parse("ds") is Mode.DS`), iterable over the registered modes in
registration order (`list(Mode)`), with each mode as an attribute (`Mode.SCALAR`).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from typing import Any, ClassVar

from dsteleop.arbitration.modes.base import ModeSpec, Quantities, check_range
from dsteleop.errors import ConfigError

#: The built-in modes, one module of this package each, in the order lists show them.
BUILTIN: tuple[str, ...] = (
    "ds", "standard", "manual", "autonomous", "scalar", "dsc", "conf_scalar",
)  # fmt: skip

_SPECS: dict[str, ModeSpec[Any, Any]] = {}
_MODES: dict[str, Mode] = {}


class _Registered(type):
    """`Mode`'s metaclass: iterating `Mode` lists the registered modes, and each is an
    attribute (`Mode.DS`)."""

    def __iter__(cls) -> Iterator[Mode]:
        return iter(tuple(_MODES.values()))

    def __len__(cls) -> int:
        return len(_MODES)

    def __getattr__(cls, attribute: str) -> Mode:
        for name, spec in _SPECS.items():
            if spec.attribute == attribute:
                return _MODES[name]
        raise AttributeError(f"no mode {attribute!r} is registered")


class Mode(str, metaclass=_Registered):
    """A registered arbitration mode (module docstring); make one with `Mode.parse`."""

    DS: ClassVar[Mode]
    S: ClassVar[Mode]
    MANUAL: ClassVar[Mode]
    AUTONOMOUS: ClassVar[Mode]
    SCALAR: ClassVar[Mode]
    DSC: ClassVar[Mode]
    CONF_SCALAR: ClassVar[Mode]

    __slots__ = ()

    @property
    def value(self) -> str:
        """Its written name."""
        return str.__str__(self)

    @property
    def name(self) -> str:
        """Its attribute on `Mode` (DS, S, MANUAL, ...)."""
        return self.spec.attribute

    @property
    def spec(self) -> ModeSpec[Any, Any]:
        """Its plug-in."""
        try:
            return _SPECS[self]  # a Mode hashes and compares as its name
        except KeyError:
            raise ConfigError(f"mode {self.value!r} is no longer registered") from None

    def __repr__(self) -> str:
        return f"Mode.{self.spec.attribute}" if self.value in _SPECS else f"Mode({self.value!r})"

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        # A module-level function, which every pickler (Ray's cloudpickle too) refers to by
        # name; a bound classmethod would be pickled by value, without this registry.
        return (_by_name, (self.value,))

    @classmethod
    def parse(cls, text: str) -> Mode:
        """The registered mode named `text` (any case; its attribute name too)."""
        t = str(text).strip()
        for name, spec in _SPECS.items():
            if t.lower() == name.lower() or t.upper() == spec.attribute:
                return _MODES[name]
        names = ", ".join(_SPECS)
        raise ConfigError(f"unknown mode {text!r} (choose from {names})")


def _by_name(name: str) -> Mode:
    """The registered mode `name` (how a pickled Mode is restored)."""
    return Mode.parse(name)


def register(spec: ModeSpec[Any, Any]) -> Mode:
    """Add a mode; its name and attribute must be new (a ConfigError otherwise)."""
    if (
        not spec.name
        or not spec.attribute.isidentifier()
        or spec.attribute != spec.attribute.upper()
    ):
        raise ConfigError(f"mode {spec.name!r}: needs a name and an upper-case attribute name")
    for name, other in _SPECS.items():
        if name.lower() == spec.name.lower() or other.attribute == spec.attribute:
            raise ConfigError(f"mode {spec.name!r}: a mode {name!r} is registered already")
    if "." in spec.name or "=" in spec.name or "," in spec.name:
        raise ConfigError(f"mode {spec.name!r}: a name holds no '.', '=' or ','")
    _SPECS[spec.name] = spec
    mode = str.__new__(Mode, spec.name)
    _MODES[spec.name] = mode
    return mode


def unregister(mode: Mode | str) -> None:
    """Remove a registered mode (a test's own, when the test ends)."""
    m = Mode.parse(mode)
    del _SPECS[m.value], _MODES[m.value]


def registered() -> tuple[Mode, ...]:
    """The registered modes, in registration order."""
    return tuple(_MODES.values())


def default_params() -> tuple[tuple[str, Any], ...]:
    """(name, its default parameters) of every registered mode that has parameters."""
    return tuple((name, spec.params()) for name, spec in _SPECS.items() if spec.params is not None)


def params_class(name: str) -> type | None:
    """The parameter class of the mode `name` (None: it has none); unknown: ConfigError."""
    return Mode.parse(name).spec.params if name in _SPECS else _unknown_params(name)


def _unknown_params(name: str) -> type | None:
    raise ConfigError(
        f"unknown mode {name!r} in a mode parameter (modes with parameters: "
        f"{', '.join(n for n, s in _SPECS.items() if s.params is not None) or 'none'})"
    )


for _module in BUILTIN:
    register(importlib.import_module(f"{__name__}.{_module}").SPEC)

__all__ = [
    "BUILTIN",
    "Mode",
    "ModeSpec",
    "Quantities",
    "check_range",
    "default_params",
    "params_class",
    "register",
    "registered",
    "unregister",
]
