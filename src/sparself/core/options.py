"""One source of truth per option: a dataclass field holds its default and its help, and the command line
is built from the fields (:func:`add_options`, :func:`from_args`).

    size: int = option(128, "long side in px of the training images")

A field made with :func:`option` becomes ``--size`` (underscores become dashes). A ``Literal`` type names
its choices: the command line offers only those, and :func:`check_choices` (called by the dataclass's own
validation) rejects any other value, however the config was made. A bool that defaults to True becomes
``--no-<name>``, one that defaults to False ``--<name>``; its help says what the field means when True.
``bool | None`` takes auto/yes/no; a tuple of ints (or floats) is comma-separated (``--holdout 3,10``).
``cli=False`` keeps a field off the command line (set it from Python or a saved config).
"""

from __future__ import annotations

import argparse
import dataclasses
import typing
from typing import Any, Literal

from sparself.core.errors import ConfigError


def option(default: Any, help: str, *, cli: bool = True, metavar: str | None = None, flag: str | None = None):
    """A dataclass field with its help text (and its flag if not ``--<name>``) for the generated command
    line. help: what the field means (for a bool: what True does)."""
    md = {"help": help, "cli": cli, "metavar": metavar, "flag": flag}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=md)
    return dataclasses.field(default=default, metadata=md)


def _number_tuple(cast, what: str):
    """A parser of comma-separated numbers of type ``cast`` (``what`` names them in its error)."""

    def parse(text: str) -> tuple:
        try:
            return tuple(cast(x) for x in text.split(",") if x.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {text!r}") from None

    return parse


_int_tuple = _number_tuple(int, "integers")
_float_tuple = _number_tuple(float, "numbers")


def _float_tuple_or_auto(text: str) -> tuple | None:
    return None if text.strip() == "auto" else _float_tuple(text)


def _str_tuple(text: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in text.split(",") if x.strip())


def _auto_bool(text: str) -> bool | None:
    try:
        return {"auto": None, "yes": True, "no": False}[text]
    except KeyError:
        raise argparse.ArgumentTypeError(f"expected auto, yes or no, got {text!r}") from None


def literal_choices(cls: type) -> dict[str, tuple]:
    """The fields of dataclass ``cls`` typed ``Literal[...]``: name -> the allowed values."""
    hints = typing.get_type_hints(cls)
    return {
        f.name: typing.get_args(hints[f.name])
        for f in dataclasses.fields(cls)
        if typing.get_origin(hints[f.name]) is Literal
    }


def check_choices(config: Any) -> None:
    """Raise ConfigError naming the first ``Literal`` field of dataclass ``config`` whose value is not one
    of its choices."""
    for name, allowed in literal_choices(type(config)).items():
        value = getattr(config, name)
        if value not in allowed:
            raise ConfigError(f"{name} must be one of {', '.join(map(str, allowed))}, got {value!r}")


def _kind(f: dataclasses.Field) -> str:
    return str(f.type).replace(" ", "")


def _fmt(v) -> str:
    if isinstance(v, tuple):
        return ",".join(str(x) for x in v) or "none"
    return "auto" if v is None else str(v)


def _type(kind: str):
    if kind.startswith("tuple[int"):
        return _int_tuple
    if kind.startswith("tuple[str"):
        return _str_tuple
    if kind.startswith("tuple[float"):
        return _float_tuple_or_auto if kind.endswith("|None") else _float_tuple
    return {"int": int, "float": float, "int|None": int, "float|None": float, "bool|None": _auto_bool}.get(kind, str)


def add_options(
    p: argparse._ActionsContainer,  # a parser or an argument group
    cls,
    skip: tuple[str, ...] = (),
    *,
    unset: bool = False,
    notes: dict[str, str] | None = None,
) -> None:
    """Add an argument for every :func:`option` field of dataclass ``cls`` (except ``skip``). unset: an
    option not given is left out of the parsed arguments (its default is applied later); notes: text
    appended to some fields' help."""
    choices = literal_choices(cls)
    for f in dataclasses.fields(cls):
        md = f.metadata
        if f.name in skip or "help" not in md or not md["cli"]:
            continue
        note = (notes or {}).get(f.name, "")
        flag, kind = md["flag"] or "--" + f.name.replace("_", "-"), _kind(f)
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        given = argparse.SUPPRESS if unset else default
        if kind == "bool":
            neg = default is True
            p.add_argument(
                "--no-" + flag[2:] if neg else flag,
                dest=f.name,
                default=given,
                action="store_false" if neg else "store_true",
                help=f"{md['help']} ({'on by default; this flag turns it off' if neg else 'off by default'}{note})",
            )
            continue
        p.add_argument(
            flag,
            dest=f.name,
            default=given,
            choices=choices.get(f.name),
            type=_type(kind),
            metavar=md["metavar"] or ("auto|yes|no" if kind == "bool|None" else None),
            help=f"{md['help']} (default {_fmt(default)}{note})",
        )


def from_args(cls, args: argparse.Namespace, skip: tuple[str, ...] = (), **fixed):
    """An instance of ``cls`` from the parsed arguments that :func:`add_options` made (except ``skip``),
    plus ``fixed``."""
    names = {f.name for f in dataclasses.fields(cls)} - set(skip)
    given = {k: v for k, v in vars(args).items() if k in names}
    return cls(**{**given, **fixed})


def given(cls, args: argparse.Namespace) -> dict:
    """The fields of ``cls`` that were given on a command line built with ``add_options(unset=True)``."""
    names = {f.name for f in dataclasses.fields(cls)}
    return {k: v for k, v in vars(args).items() if k in names}
