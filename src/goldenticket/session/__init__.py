"""Real-robot search sessions scored by a person: the protocol and its store, the web app, and
the robot's client."""

from goldenticket.session.client import Client
from goldenticket.session.protocol import NextEpisode, Plan, ScoreConflict, Session, StoreLost

__all__ = ["Client", "NextEpisode", "Plan", "ScoreConflict", "Session", "StoreLost"]
