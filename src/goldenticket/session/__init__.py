"""Real-robot search sessions scored by a person: the plan and its race, the store, the verdict,
the web app, and the robot's client."""

from goldenticket.session.client import Client
from goldenticket.session.episode import NextEpisode
from goldenticket.session.folder import ScoreConflict, Session
from goldenticket.session.race import Plan
from goldenticket.session.store import StoreLost
from goldenticket.session.verdict import SessionVerdict

__all__ = ["Client", "NextEpisode", "Plan", "ScoreConflict", "Session", "SessionVerdict", "StoreLost"]
