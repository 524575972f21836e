"""The terminal UI's screens, each with its .tcss."""
