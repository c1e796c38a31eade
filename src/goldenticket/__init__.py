"""goldenticket: golden-ticket search for frozen diffusion and flow-matching robot policies."""

__version__ = "0.1.0"
