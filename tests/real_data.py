"""Where the tests find ../shared/data (or BLENDGEN_SHARED_DATA), and the CLI as a subprocess."""

import os
import subprocess
import sys
from pathlib import Path

DATA = Path(os.environ.get("BLENDGEN_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
BDD = DATA / "real" / "bdd_street_photos"


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blendgen.cli", *args], capture_output=True, text=True, timeout=900)
