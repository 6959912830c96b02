"""LinuxCNC as the height controller's CNC: the bridge, the machine configuration, the run.

Nothing is imported here: :mod:`.hal_component`, :mod:`.display` and :mod:`.z_filter` run on the
system's Python inside LinuxCNC and import only :mod:`.protocol` and the standard library.
"""

from __future__ import annotations

from importlib import import_module

# the public API (name: module), imported on first use: importing the package
# loads nothing else. Its own copy of ladrc_contract.lazy_api: the LinuxCNC-side modules run on
# the system Python, where only the standard library and protocol are there
_EXPORTS = {
    'LinuxCnc': 'machine',
    'LinuxCncError': 'machine',
    'RunSettings': 'machine',
    'missing': 'machine',
    'render_run_config': 'machine',
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """Import a public name from its module on first use."""
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}') from None
    value = getattr(import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
