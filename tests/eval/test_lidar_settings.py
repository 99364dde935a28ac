"""The lidar run's settings (:mod:`sanav_mj.eval.lidar`): the sensed grid's log-odds rule per
footprint mode."""

from __future__ import annotations

from sanav_mj.eval.lidar import lidar_controller, lidar_grid
from sanav_mj.eval.prepare import footprint_spec
from sanav_mj.mapping.live_grid import LiveGridConfig
from sanav_mj.scene import load_scenario


def test_the_discs_mode_outvotes_stray_returns_and_the_disc_mode_keeps_one_return_non_free():
    discs, disc = lidar_grid(footprint_spec("sa-mpc", "discs")), lidar_grid(footprint_spec())
    assert discs == LiveGridConfig() and discs.floor_at == 0.5 and discs.l_min == -5.0
    # the disc mode (0.05 m cells): one return makes any cell non-free at once
    assert disc == LiveGridConfig(l_min=-1.0, floor_at=None)
    assert disc.l_min + disc.l_occ > disc.free_thresh
    sc = load_scenario("single_rect")
    assert lidar_controller(sc, footprint_spec()).config.map.grid == disc
    # the discs mode's run (range noise 0.02 m, 0.025 m cells): the sub-cell evidence on
    ctrl = lidar_controller(sc, footprint_spec("sa-mpc", "discs"))
    assert ctrl.config.map.grid == LiveGridConfig(sub_cells=2)
    assert type(ctrl.map.grid).__name__ == "SubcellGrid"


def test_the_sub_cell_evidence_is_used_only_where_the_noise_keeps_slivers_occupied():
    discs = footprint_spec("sa-mpc", "discs")
    assert lidar_grid(discs, 0.02, 0.025).sub_cells == 2
    assert lidar_grid(discs, 0.0, 0.025).sub_cells == 2
    # 0.03 m of noise on 0.0125 m sub-cells: a sliver holds 0.24 of the beams reaching it < f* 0.29
    assert lidar_grid(discs, 0.03, 0.025) == LiveGridConfig()
    assert lidar_grid(footprint_spec(), 0.02, 0.05) == LiveGridConfig(l_min=-1.0, floor_at=None)
