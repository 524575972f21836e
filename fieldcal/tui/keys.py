"""The keys of each screen, in words: the help screen shows them, and ``fieldcal tui --help``
lists them (so no Textual import here). Lines fit the help box (74 columns)."""
from __future__ import annotations

SIM_KEYS = """\
r   ready: the unit is in place (the simulator carries it there); after a
    wrong placement, the simulator corrects it
s   skip this position (the solve uses the others); asks first
u   back to the last skipped position; asks first if this step has begun
o   redo this step from the placement; asks first
a   abort: stop the run for good, the session is kept; asks first
b   bump the fixture (simulator): a dwell in progress restarts
w   place the unit in a wrong position on purpose (simulator)
1-9 which position the unit is in, when the banner asks (positions in any
    order that gravity cannot tell apart)
v   the results, once the run has ended; Esc there comes back here
?   this help
q   quit; mid-run it asks first (the unfinished session is kept);
    ctrl+q and ctrl+c ask the same
A question is answered by its key again or y; any other key says no."""

LIVE_KEYS = """\
r   ready: the unit is in place (place it as the screen shows, then r)
s   skip this position (the solve uses the others); asks first
u   back to the last skipped position; asks first if this step has begun
o   redo this step from the placement; asks first
a   abort: stop the run for good (the table stops), the session is kept;
    asks first
1-9 which position the unit is in, when the banner asks (positions in any
    order that gravity cannot tell apart)
v   the results, once the run has ended; Esc there comes back here
?   this help
q   quit (the table stops; the session is kept); mid-run it asks first;
    ctrl+q and ctrl+c ask the same
A question is answered by its key again or y; any other key says no."""

REPLAY_KEYS = """\
A replay applies the operator actions recorded in the session, at the
recorded samples; the operator keys are ignored.

v   the results, once the replay has ended; Esc there comes back here
?   this help          q   quit"""


SETUP_KEYS = """\
Choose the device config (or type the path of one), the ports, the
procedure, the station, the operator and the unit's serial, then start.

Tab, shift+Tab  next, previous field; Enter in a text field: next field
ctrl+s          start (anywhere), or click Start; nothing else starts
ctrl+r          resume the unfinished session chosen (listed when there are
                any in --out; a live one on the ports shown)
Esc             quit; q quits too, outside a text field
?               this help (outside a text field)"""
