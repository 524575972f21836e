"""Wire protocols: byte streams in, sample chunks out (and, for the simulator, the reverse)."""
