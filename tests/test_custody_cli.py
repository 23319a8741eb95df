"""``ocreach custody``: files written, JSON contents, and clear errors for bad input."""
from __future__ import annotations

import json

import pytest

from ocreach.cli import main


def test_custody_cli_writes_json_md_and_figures(tmp_path, capsys):
    out = tmp_path / "c"
    rc = main(["custody", "custody-l4", "--fov", "0.5,6", "--horizons", "0.25,0.5", "--step", "0.25",
               "--tol", "0.02", "--samples", "10", "--mc", "300", "--out", str(out)])
    assert rc == 0
    data = json.loads((out / "custody.json").read_text())
    cases = data["cases"]
    assert len(cases) == 2 and {c["fov_deg"] for c in cases} == {0.5, 6.0}
    for c in cases:
        assert c["problem"] == "custody-l4" and c["control_set"] == "box" and c["observer"] == "geocentre"
        assert {"t_safe_days", "t_loss_days", "horizons"} <= set(c)
        for h in c["horizons"]:
            assert h["outer_radius_km"] >= h["inner_radius_km"] > 0
            assert h["meb_radius_km"] == h["inner_radius_km"]
            assert 0 <= h["probability"] <= 1 and 0 <= h["mc_fraction_in_fov"] <= 1
    small, big = sorted(cases, key=lambda c: c["fov_deg"])
    # 6 deg holds for the whole half day; 0.5 deg (1424 km across at 3.3e5 km) too at 0.5 d (r ~ 90 km)
    assert big["t_loss_days"] is None and big["t_safe_days"] == 0.5
    mc = data["mc_validation"]["custody-l4:box"]
    assert all(m["outside_outer"] == 0 and m["above_support"] == 0 and "points" not in m for m in mc)
    assert (out / "custody.md").read_text().startswith("# Custody")
    assert (out / "custody-l4_box_xy.png").stat().st_size > 0
    assert (out / "custody-l4_box_focal_geocentre.png").stat().st_size > 0
    assert all(c["converged"] and c["search_message"] == "" for c in cases)
    from PIL import Image

    with Image.open(out / "custody-l4_box_xy.png") as im:  # 8-bit palette figures, 100 dpi
        assert im.mode == "P" and round(im.info["dpi"][0]) == 100


def test_palette_png_is_smaller_and_keeps_the_picture(tmp_path):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    import numpy as np
    from PIL import Image

    from ocreach.reach.plot import save_figure

    def fig():
        f, ax = plt.subplots(figsize=(4, 3))
        t = np.linspace(0, 6, 400)
        for k in range(5):
            ax.plot(t, np.sin(t + k), lw=1.5)
        ax.scatter(*np.random.default_rng(0).normal(size=(2, 300)), s=4, alpha=0.5)
        return f

    full = save_figure(fig(), tmp_path / "full.png", dpi=100)
    small = save_figure(fig(), tmp_path / "small.png", dpi=100, palette=True)
    assert small.stat().st_size < 0.6 * full.stat().st_size
    with Image.open(full) as a, Image.open(small) as b:
        assert b.mode == "P" and a.size == b.size
        A = np.asarray(a.convert("RGB"), dtype=float)
        B = np.asarray(b.convert("RGB"), dtype=float)
    assert np.abs(A - B).mean() < 2.0 and np.abs(A - B).max() <= 64  # 0-255 scale


@pytest.mark.parametrize("argv,needle", [
    (["--fov", "0"], "fov"), (["--fov", "180"], "fov"), (["--fov", "x"], "--fov"),
    (["--fov", "1", "--p", "1.5"], "probability"), (["--fov", "1", "--p", "0"], "probability"),
    (["--fov", "1", "--observer", "moon"], "--observer"),
    (["--fov", "1", "--observer", "ground:1,2"], "three numbers"),
])
def test_custody_cli_bad_input(tmp_path, capsys, argv, needle):
    rc = main(["custody", "custody-l1", "--no-figures", "--out", str(tmp_path), *argv])
    assert rc == 2
    assert needle in capsys.readouterr().err
