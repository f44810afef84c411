"""Real-data VO regression: 7-Scenes redkitchen frames 0-99 with the default
:class:`spgeo.apps.vo_run.VORunConfig` (resolution and :class:`spgeo.vo.OdometryConfig`), per-frame Sim(3) ATE below a bound and no frame lost.

Skips when ``../shared/data/7scenes_redkitchen_dev`` (or ``$SPGEO_SHARED_DATA``)
is absent.
"""
import pytest

from conftest import shared_data_dir
from spgeo.apps.vo_run import VORunConfig, run_dataset

#: per-frame ATE bounds (metres) of the default config, by front-end
ATE_BOUND_M = {"classical": 0.018, "depth": 0.011}


@pytest.mark.slow
@pytest.mark.parametrize("frontend", sorted(ATE_BOUND_M))
def test_7scenes_vo_regression(frontend):
    path = shared_data_dir() / "7scenes_redkitchen_dev"
    if not path.is_dir():
        pytest.skip(f"shared 7-Scenes sequence not found at {path}")
    run = run_dataset("7scenes", path, "0:100",
                      VORunConfig(frontend=frontend, progress=False))
    assert run.n_frames == 100
    counts = run.status_counts()
    assert counts.get("lost", 0) == 0, counts
    assert counts.get("keyframe", 0) >= 2, counts
    ate = run.ate()
    assert ate is not None
    pf = ate["per-frame"]
    assert pf.n_associated >= 60
    assert pf.rmse < ATE_BOUND_M[frontend], (
        f"{frontend}: per-frame ATE {pf.rmse:.4f} m >= bound {ATE_BOUND_M[frontend]} m")
