"""A virtual MIMU in a cube fixture on a single-axis rate table (physics only)."""
from drivers.noise import TriadNoise
from drivers.sim.physics import MimuSimulator, Segment, TriadTruth, lower_triangular_k

__all__ = ["MimuSimulator", "Segment", "TriadNoise", "TriadTruth", "lower_triangular_k"]
