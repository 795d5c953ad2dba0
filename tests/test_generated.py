"""generated/ is what the emitter makes today: regenerating changes nothing."""
import filecmp
from pathlib import Path

from skigen.emit.shipped import generate_all

ROOT = Path(__file__).resolve().parents[1] / "generated"


def test_generated_sources_are_up_to_date(tmp_path):
    fresh = generate_all(tmp_path)
    assert fresh, "nothing was generated"
    stale = [str(f.relative_to(tmp_path)) for f in fresh
             if not (ROOT / f.relative_to(tmp_path)).is_file()
             or not filecmp.cmp(f, ROOT / f.relative_to(tmp_path), shallow=False)]
    extra = sorted(str(p.relative_to(ROOT)) for p in ROOT.rglob("*.[ch]")
                   if not (tmp_path / p.relative_to(ROOT)).is_file())
    assert not stale and not extra, (f"generated/ is out of date (run `make generate`): changed {stale}, "
                                     f"no longer emitted {extra}")
