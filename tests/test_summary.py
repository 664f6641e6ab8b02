"""``sim.stats.summary()``: a dict for programs that prints as a table for people."""
import json
import re

import skfem_affine as sa


def run(**kwargs):
    sim = sa.scenes.cantilever(resolution=1, **kwargs)
    for _ in sim.run(3):
        pass
    return sim.stats.summary()


def test_the_summary_prints_a_table_of_short_numbers():
    summary = run()
    text = str(summary)
    assert repr(summary) == text and not text.startswith("{")
    rows = text.splitlines()
    assert rows[0].split() == ["frames", "3"]
    assert any(r.startswith("wall time") and r.endswith(" s") for r in rows)
    assert any(r.strip().startswith("assembly") and "% of wall" in r for r in rows)
    digits = [len(re.sub(r"\D", "", m.split("e")[0]).lstrip("0")) for m in re.findall(r"\d[\d.]*(?:e[-+]\d+)?", text)]
    assert max(digits) <= 4, text  # at most four significant digits


def test_the_summary_is_still_the_dict_programs_read():
    summary = run(reducer=sa.Affinification())
    assert isinstance(summary, dict) and summary["frames"] == 3 and summary["wall_s"] > 0
    assert set(summary) >= {"frames", "wall_s", "frames_per_s", "mean_dofs", "assembly_s", "max_estimated_error"}
    assert json.loads(json.dumps(summary)) == dict(summary)
    text = str(summary)
    assert "largest estimated error" in text and "error unit" in text
