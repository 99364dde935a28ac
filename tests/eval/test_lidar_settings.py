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
    assert lidar_controller(sc, footprint_spec("sa-mpc", "discs")).config.map.grid == discs
