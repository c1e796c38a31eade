"""Studies that compose rollouts and evaluation: diversity of noise sources, Pareto fronts."""
