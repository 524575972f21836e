"""Runs: the spec, benches (simulated, pty, live device), operators, replay, progress."""
