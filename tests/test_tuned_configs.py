"""The tuned configurations the docs' claims rest on (docs/tuned/README.md): each is a
`--config` file the commands read, the per-cell folders cover the sweep's cells, each file
records the world it was tuned in, and the disagreement world's headline holds on held-out
people as a rate (not bit for bit)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import pytest

from dsteleop.app.cli.options import config_from_file
from dsteleop.app.cli.world_options import add_world_arguments, world_overrides
from dsteleop.app.study import batch, planar, results, sweep
from dsteleop.app.study import summary as study_summary
from dsteleop.app.study.objects import Objects
from dsteleop.arbitration import Mode

TUNED = Path(__file__).resolve().parents[1] / "docs" / "tuned"
CELL_FOLDERS = ("cells", "equal-count")


def _configs() -> list[Path]:
    """The told-goal worlds' files (DS and the scalar; the objects world's: `OBJECTS`)."""
    parts = ("runs", "objects")
    return sorted(
        p for p in TUNED.rglob("*.json") if not set(parts) & set(p.relative_to(TUNED).parts)
    )


def _disagreement_world() -> dict[str, Any]:
    """SimConfig's fields for `--world disagreement`, as sim and tune read the option."""
    parser = argparse.ArgumentParser()
    add_world_arguments(parser)
    return world_overrides(parser.parse_args(["--world", "disagreement"]))


def test_every_shipped_configuration_is_a_config_file_with_both_modes_tuned() -> None:
    files = _configs()
    assert len(files) == 2 * 7 + 2
    for path in files:
        arb = config_from_file(path, [])
        data = json.loads(path.read_text())
        assert set(data["objective"]) == {"DS", "scalar"}, path
        for mode, found in data["objective"].items():
            for name, value in found["params"].items():
                assert data["arbitration"][name] == value, (path, mode, name)
        # The scalar's tuned cap is the arbiter's: no file leaves a mode at its defaults.
        assert arb.params_of("scalar").cap < 1.0 and arb.params_of("DS").cap_translation < 1.0


@pytest.mark.parametrize("folder", CELL_FOLDERS)
def test_the_cell_folders_cover_the_axes_design(folder: str) -> None:
    cells = sweep.design_cells(sweep.default_grid(), "axes", sweep.centre(planar.SimConfig()))
    names = {sweep.cell_name(c) for c in cells}
    assert {p.stem for p in (TUNED / folder).glob("*.json")} - {"disagreement"} == names


def test_the_disagreement_files_record_the_world_they_were_tuned_in() -> None:
    preset = _disagreement_world()
    for path in (TUNED / "disagreement.json", TUNED / "equal-count" / "disagreement.json"):
        world = json.loads(path.read_text())["world"]["overrides"]
        assert world["world"] == {"goal_sigma_m": 0.0}
        stated = preset["grasps"].to_dict()
        assert world["grasps"] == {k: v for k, v in stated.items() if k != "names"}


def test_the_tuned_disagreement_headline_holds_on_held_out_people() -> None:
    """docs/sim.md (a): with the shipped configuration, people who disagree with the robot's
    grasp succeed under DS, in their own grasp, and mostly fail under S (held out: 0.998 and
    0.383 over 1000 people); 60 people of seed 1 with wide margins."""
    world = _disagreement_world()
    arb = config_from_file(TUNED / "equal-count" / "disagreement.json", [])
    cfg = planar.SimConfig(
        trajectories=60,
        seed=1,
        max_paths=0,
        modes=(Mode.S, Mode.DS, Mode.SCALAR),
        arbitration=arb,
        **world,
    )
    res = results.merge(cfg, [batch.run_chunk(cfg, list(range(cfg.trajectories)))])
    d = study_summary.disagreement_summary(res)["modes"]
    ds, s = d["DS"]["prefers_other_grasp"], d["S"]["prefers_other_grasp"]
    assert ds["success_rate"]["estimate"] >= 0.9
    assert ds["successes_in"]["side"] >= 0.9 * ds["successes_in"]["top"] + 1
    assert s["success_rate"]["estimate"] <= 0.6
    assert d["scalar"]["prefers_other_grasp"]["success_rate"]["estimate"] >= 0.8


OBJECTS = TUNED / "objects"


def test_the_objects_worlds_files_give_each_tuned_mode_its_own_configuration() -> None:
    """docs/tuned/README.md, the objects world (the five cells of the axes design, 32 trials
    each): DSC, DS, conf_scalar and the scalar each run held out with what they tuned,
    on the same people: the fields they share (kappa, p, q, b, window) from each mode's own
    section, the caps and levers from the merged arbitration."""
    from dsteleop.app.cli.sim import study_configuration

    world = planar.SimConfig().world.replace(goal_sigma_m=0.0)  # as `--world objects` sets it
    cfg = planar.SimConfig(objects=Objects(), world=world)
    cells = {
        sweep.cell_name(c)
        for c in sweep.design_cells(sweep.default_grid(cfg), "axes", sweep.centre(cfg))
    }
    files = sorted(OBJECTS.glob("*.json"))
    assert files and {p.stem for p in files} <= cells
    for path in files:
        arb, own = study_configuration(path, [])
        data = json.loads(path.read_text())
        assert set(data["objective"]) == {"DSC", "DS", "conf_scalar", "scalar"}, path
        by_mode = {m.value: a for m, a in own}
        for mode, found in data["objective"].items():
            assert found["trial"] is not None and found["value"] > 0.5, (path, mode)
            for name, value in found["params"].items():
                assert by_mode[mode].to_dict()[name] == value, (path, mode, name)
        assert arb.params_of("DSC").power == data["objective"]["DSC"]["params"]["DSC.power"]
        study = planar.SimConfig(objects=Objects(), arbitration=arb, mode_arbitration=own)
        assert study.arbitration_of(Mode.DSC) == by_mode["DSC"]
