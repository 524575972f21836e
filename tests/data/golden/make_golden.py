"""Write the golden sessions with the code at commit 58c3726 (run from that tree)."""
import sys
from pathlib import Path
from fieldcal.earth import Station
from fieldcal.procedure.positions import load_procedure, parse_procedure
from fieldcal.run.runner import OperatorScript, RunSpec, open_run, resume_headless, run_headless
from fieldcal.run.replay import replay
from fieldcal.tui.source import READY, SimSource
from fieldcal.procedure import events as ev

out = Path(sys.argv[1])
text = load_procedure("field-18").text
text = text.replace("name: field-18", "name: golden-mini").replace("dwell_s: 200", "dwell_s: 3") \
    .replace("rate_step: {rate_deg_s: 10, turns: 1, ramp_s: 2, settle_s: 1}",
             "rate_step: {rate_deg_s: 60, turns: 1, ramp_s: 3, settle_s: 1}")
proc = parse_procedure(text, "golden-mini.yaml")
station = Station(40.0, 50.0)
RATE = 20.0

# A: headless with mishaps, crashed before the 6th step record, resumed.
spec = RunSpec(proc, station, seed=7, rate_hz=RATE,
               script=OperatorScript(handling_s=2.0, bump_step=2, wrong_step=4, skip_steps=(9,)))
whole = run_headless(spec, out / "headless-resumed")
expected = whole.parameters.read_bytes()
log = out / "headless-resumed" / "log.jsonl"
data = log.read_bytes(); offset, seen = 0, -1
for line in data.splitlines(keepends=True):
    if b'"type":"step"' in line:
        seen += 1
        if seen == 5: break
    offset += len(line)
log.write_bytes(data[:offset]); (out / "headless-resumed" / "parameters.yaml").unlink()
r = resume_headless(open_run(out / "headless-resumed"))
assert r.parameters.read_bytes() == expected
assert replay(open_run(out / "headless-resumed")).identical is True
(out / "headless-resumed.expected.yaml").write_bytes(expected)

# B: a TUI simulator run (speed 0), ready at each step, quit while waiting at step 7.
class Sink:
    def __init__(self): self.done = 0; self.source = None; self.outcome = None
    def update(self, items, telemetry):
        self.done += sum(isinstance(i, ev.StepComplete) for i in items)
        if telemetry.waiting:
            if self.done >= 6: self.source.stop()
            else: self.source.send(READY)
    def finished(self, o): self.outcome = o
tspec = RunSpec(proc, station, seed=8, rate_hz=RATE, script=OperatorScript(handling_s=2.0))
sink = Sink()
src = sink.source = SimSource(tspec, sink, speed=0, session_dir=out / "tui-quit")
o = src.run()
print(o.status, o.message, o.completed)
