"""Real-robot search sessions scored by a person: the protocol and its store, the web app."""

from goldenticket.session.protocol import NextEpisode, Plan, ScoreConflict, Session, StoreLost

__all__ = ["NextEpisode", "Plan", "ScoreConflict", "Session", "StoreLost"]
