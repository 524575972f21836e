"""The ``fieldcal`` command: one module per command group. Kept light: heavy imports happen inside commands."""
