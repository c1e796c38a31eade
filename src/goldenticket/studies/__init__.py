"""Studies that compose search and evaluation: diversity of stochastic tickets, ..."""
