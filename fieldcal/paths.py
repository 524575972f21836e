"""Where the station's shipped files live; stdlib only, so a command's --help can list them."""
from pathlib import Path

CONFIGS_DIR = Path(__file__).resolve().parent.parent / "configs"
RECORDINGS_DIR = CONFIGS_DIR / "recordings"  # import maps
