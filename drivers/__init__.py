"""Bytes <-> sample chunks: transports, wire protocols, turntables and the simulator.

This package never imports :mod:`fieldcal`; the station depends on it, not the reverse.
"""
