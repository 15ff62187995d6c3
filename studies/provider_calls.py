"""How a study asks its providers: finding, naming and calling them, and what they raise.

A controller provider is a callable ``provider(case, known) -> {label: controller}``: it gets the
`studies.CaseStudy` being run and the plant known to its controllers (`CaseStudy.known_plant`), and
returns controllers designed from it. An answer provider is ``provider(case) -> {item: answers}``.
A case lists its providers (`CaseStudy.providers`, `CaseStudy.answer_providers`; its own designs are
`studies.providers`). A provider with nothing for a case (no design of its kind) raises
`NotProvided`, which the run notes instead of failing.

The command line names providers as ``MODULE:FUNCTION`` strings (``--provider``); `find` turns one
into its function and `resolve` a list of functions and strings into functions, before any work.
This module knows no case and no design: the runner, the answers and the command line use it
without importing the designs.
"""

from __future__ import annotations

import copy
import importlib
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from models import Block, interrupts

#: provider(case, known) -> {label: controller}
Provider = Callable[..., Mapping[str, Any]]
#: provider(case) -> {homework item: answers}
AnswerProvider = Callable[..., Mapping[str, Any]]


class NotProvided(LookupError):
    """Raised by a provider that has nothing for this case (no design of its kind): noted, not a failure."""


class ProviderNotFound(LookupError):
    """A ``module:function`` provider whose module cannot be imported or has no such function."""


# ---------------------------------------------------------------------------- naming and finding
def find(spec: str) -> Callable:
    """The function a ``module:function`` string names (its module imported), named as given
    (`Named` when the function's own module and name differ, as for a re-exported one).

    Raises
    ------
    ProviderNotFound
        Naming the provider when its module does not exist or has no such function (an error
        raised while importing an existing module propagates as it is).
    """
    module_name, _, function_name = spec.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        if err.name and (module_name == err.name or module_name.startswith(err.name + ".")):
            raise ProviderNotFound(f"provider {spec!r}: no module named {err.name!r}") from None
        raise
    function = getattr(module, function_name, None)
    if not callable(function):
        raise ProviderNotFound(f"provider {spec!r}: module {module_name} has no function {function_name}()")
    return function if name_of(function) == spec else Named(spec, function)


@dataclass(frozen=True)
class Unavailable:
    """A ``module:function`` provider that could not be found or imported, run without it.

    Called, it provides nothing (`NotProvided` with `reason`), so the study notes it where the
    provider stands in its list: "``name``: skipped, ``reason``".
    """

    name: str
    reason: str

    def __call__(self, *args, **kwargs):
        """Provide nothing: `NotProvided` with the reason."""
        raise NotProvided(self.reason)


@dataclass(frozen=True)
class Named:
    """A provider found from a ``module:function`` string that names it otherwise (a re-exported
    function): called, it is `function`; notes and run.json name it `name`, as it was given."""

    name: str
    function: Callable

    def __call__(self, *args, **kwargs):
        """What `function` returns for these arguments."""
        return self.function(*args, **kwargs)


def unavailable(spec: str, err: Exception) -> Unavailable:
    """The stand-in of the provider `spec` that `find` refused with `err` (not found, or failed to import)."""
    if isinstance(err, ProviderNotFound):
        return Unavailable(spec, str(err).split(": ", 1)[1])
    return Unavailable(spec, f"importing {spec.partition(':')[0]} failed: {type(err).__name__}: {err}")


def name_of(provider) -> str:
    """How notes and run.json name a provider: ``module:function`` (a stand-in's own name)."""
    if isinstance(provider, (Unavailable, Named)):
        return provider.name
    if isinstance(provider, str):
        return provider
    module = getattr(provider, "__module__", None) or type(provider).__module__
    function = getattr(provider, "__qualname__", None) or type(provider).__qualname__
    return f"{module}:{function}"


def _is_spec(value) -> bool:
    """Whether `value` is a ``module:function`` string (one colon, neither side blank)."""
    return isinstance(value, str) and value.count(":") == 1 and all(part.strip() for part in value.split(":"))


def resolve(values, what: str = "providers", strict: bool = False) -> tuple:
    """`values` (a list or tuple of providers, or of ``module:function`` strings naming them) as a tuple
    of callables, each string found now (`find`).

    A string whose provider is not found or fails to import becomes an `Unavailable` stand-in (the
    study notes it), or with `strict` raises.

    Raises
    ------
    TypeError, ValueError
        Naming `what`, when `values` is a single string or not a list of callables and strings.
    ProviderNotFound, or the error importing the provider's module raised
        With `strict`, for the first string that names no provider.
    """
    if isinstance(values, str) or not isinstance(values, (list, tuple)):
        raise TypeError(
            f"{what} must be a list of providers (functions, or 'module:function' strings), "
            f"got {type(values).__name__} {values!r}"
        )
    for value in values:
        if not (callable(value) or _is_spec(value)):
            raise ValueError(f"{what}: each provider is a function or 'module:function', got {value!r}")
    found = []
    for value in values:
        if callable(value):
            found.append(value)
            continue
        try:
            found.append(find(value))
        except Exception as err:  # not found, or failing to import: noted unless strict
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            if strict:
                raise
            found.append(unavailable(value, err))
    return tuple(found)


def _where(err: BaseException) -> str:
    """``file:line`` of the innermost frame `err` was raised in."""
    where = traceback.extract_tb(err.__traceback__)[-1]
    return f"{where.filename}:{where.lineno}"


def unbuildable(name: str, returned) -> list[str]:
    """A note naming provider `name` for each Block of its `returned` {label: controller} whose CasADi
    expression raises when built (on a copy: the Block itself is left as it came). Such a Block is
    kept: its rows fail with the same error, and the other controllers run."""
    notes = []
    for label, controller in returned.items() if isinstance(returned, Mapping) else ():
        if isinstance(controller, Block):
            try:
                copy.copy(controller).casadi_step  # noqa: B018 (building the expression is the check)
            except Exception as err:
                if interrupts.is_interrupt(err):
                    raise KeyboardInterrupt from err
                notes.append(f"{name}: {label!r} failed to build ({type(err).__name__}: {err}; at {_where(err)})")
    return notes


def call_all(providers: Sequence[Callable], *args, strict: bool = False) -> tuple[list, list]:
    """Call each provider with `args`.

    A provider that raises is noted and skipped, or with `strict` raised; one that raises
    `NotProvided` (an `Unavailable` one included) is noted in either case. A Block whose expression
    raises when built is noted naming its provider (`unbuildable`) and kept: its rows fail.

    Returns
    -------
    results : list of (provider's name, returned value) for the providers that answered
    notes : one line per provider skipped or failed
    """
    results, notes = [], []
    for provider in providers:
        name = name_of(provider)
        try:
            results.append((name, provider(*args)))
            notes += unbuildable(name, results[-1][1])
        except NotProvided as err:
            notes.append(f"{name}: skipped, {err}")
        except Exception as err:
            if interrupts.is_interrupt(err):
                raise KeyboardInterrupt from err
            if strict:
                raise
            notes.append(f"{name}: failed ({type(err).__name__}: {err}; at {_where(err)})")
    return results, notes
