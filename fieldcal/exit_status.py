"""The exit statuses that say what became of a calibration, shared by the command line and the
terminal UI (both end a process with them): beside acceptance, whose verdict sets the first,
and free of imports, so that a front end reads them without loading a command or a solver."""

# The exit status of a calibration that finished but failed its product's acceptance limits
# (0: passed; 1: not calibrated; 2: bad input).
EXIT_FAILED_SPEC = 3
EXIT_SOME_FAILED = 1  # `fieldcal resolve`: some sessions could not be re-solved
