"""docs/fleet.md is run top to bottom (``tools/docgen.py``): three stores created, a fleet update, its status and a
second update that assimilates only the new dataset; every output it shows must be what the current code prints."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import docgen  # noqa: E402

sys.path.remove(str(ROOT / "tools"))


def test_fleet_page_prints_what_it_shows(tmp_path):
    assert docgen.run_guide(ROOT / "docs" / "fleet.md", folder=tmp_path) == []
    assert (tmp_path / "fleet" / ".seqbayes-fleet.json").is_file()
    assert sorted(p.name for p in (tmp_path / "fleet").glob("*.nc")) == ["bridge-a.nc", "bridge-b.nc", "bridge-c.nc"]
