"""Black-box search for golden tickets: each method's settings (`methods`), pure ask/tell optimizers,
the budgeted driver and its adapter to whatever runs episodes. A name here imports its module when it
is first used, so that config reads the methods' settings without loading numpy."""

import importlib

_MODULES = {  # each name -> the module that defines it
    "query_evaluator": "adapter",
    **dict.fromkeys(("Candidate", "EpisodeOutcome", "SearchResult", "run_search"), "driver"),
    **dict.fromkeys(("METHODS", "method", "method_settings", "RandomSearchSettings", "CEMSettings",
                     "ZerothOrderSettings", "CEMRacingSettings", "CEMBoundsSettings", "CMAESSettings",
                     "TiledThenFullSettings", "PortfolioSettings", "ModelBasedSettings", "TPESettings",
                     "GPSettings"), "methods"),
    **dict.fromkeys(("CEM", "CMAES", "OPTIMIZERS", "CEMRacing", "RandomSearch", "ZerothOrder",
                     "Portfolio", "make_optimizer"), "optimizers"),
    **dict.fromkeys(("Optimizer", "Query"), "protocol"),
    **dict.fromkeys(("RACE_BLOCK", "Halved", "Raced"), "racing"),
}
__all__ = sorted(_MODULES)


def __getattr__(name: str):
    """`name` from its module, imported now (PEP 562)."""
    if name not in _MODULES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_MODULES[name]}"), name)
