"""Stage stacking (engine_model.physics.stage_stacking): the sizing, the exact flow scaling of a
uniformly blocked stack, the stall criterion, stage mismatch, and the sign of the booster's
margin change behind a fixed throttle."""

import numpy as np
import pytest

from engine_model.physics.stage_stacking import StageStack


@pytest.fixture(scope="module")
def stack():
    return StageStack(n_stages=3, pr_des=1.31, w_des=100.0, T_in=320.0, P_in=1.5e5)


def test_design_point_every_stage_at_design_flow_coefficient(stack):
    T0, P0, phi = stack.run(stack.w_des, 1.0)
    np.testing.assert_allclose(phi, 1.0, rtol=1e-10)
    assert P0 / stack.P_in == pytest.approx(stack.pr_des, rel=1e-10)
    # the stage's Euler line passes through (phi_d, psi_d): the temperature rise is psi_d U^2
    assert T0 - stack.T_in == pytest.approx(3 * 0.4 * stack.u_des**2 / 1004.5, rel=1e-12)


def test_uniform_blockage_scales_the_characteristic_in_flow(stack):
    """Blocking every stage by the same fraction f gives, at flow (1 + f) W, exactly the
    velocities, work and losses of the clean stack at W: the speed line is the clean one
    scaled in flow, so its surge point keeps its pressure ratio."""
    f = np.full(3, -0.02)
    for n in (1.0, 0.85):
        for w in (80.0, 100.0):
            clean, blocked = stack.run(w, n), stack.run(0.98 * w, n, f)
            np.testing.assert_allclose(blocked[2], clean[2], rtol=1e-10)
            assert blocked[1] == pytest.approx(clean[1], rel=1e-12)
        ws, prs, _ = stack.surge_point(n)
        wsb, prsb, _ = stack.surge_point(n, f)
        assert wsb == pytest.approx(0.98 * ws, rel=1e-8)
        assert prsb == pytest.approx(prs, rel=1e-9)


def test_stall_at_the_peak_of_the_stage_characteristic(stack):
    x = stack.phi_s

    def head(x):
        phi = x * stack.phi_d
        return (1.0 - stack.tan_sum * phi) * np.exp(-stack.c_eta * (x - 1.0) ** 2)

    assert 0.6 < x < 0.9
    assert head(x) > head(x - 1e-3) and head(x) > head(x + 1e-3)


def test_rear_stage_stalls_at_high_speed_front_stage_at_low(stack):
    """Stage mismatch (Cumpsty ch. 8): throttled at design speed the density rise across
    the front stages slows the rear stages, which stall first; at part speed the density
    rise is smaller, the rear stages run fast and the first stage stalls."""
    assert stack.surge_point(1.0)[2] == 2
    assert stack.surge_point(0.8)[2] == 0


def test_capacity_loss_behind_a_fixed_throttle_raises_the_margin(stack):
    """A booster whose flow is set by the compressor behind it (fixed exit corrected flow)
    moves down its speed line toward choke when it loses flow capacity. Its constant-speed
    stall margin rises, whether the blockage is uniform, front-weighted or on the first
    stage only (the sign holds at 1.0 and 0.8 speed)."""
    for wts in (np.ones(3), np.array([1.0, 2 / 3, 1 / 3]), np.array([1.0, 0.0, 0.0])):
        f = stack.blockage_for_capacity(wts, -0.02)
        # the flow at design speed and design pressure ratio is 2 % lower
        w = stack.flow_at_pressure_ratio(stack.pr_des, 1.0, f)
        assert w == pytest.approx(98.0, rel=1e-8)
        for n in (1.0, 0.8):
            assert stack.stall_margin(n, f) > stack.stall_margin(n) + 0.2


def test_static_density_is_isentropic_from_the_total_state(stack):
    T0, P0, cx = 330.0, 1.6e5, 170.0
    c2 = cx**2 * (1.0 + stack.tan_a1**2)
    T = T0 - c2 / (2.0 * 1004.5)
    rho0 = P0 / (1004.5 * 0.4 / 1.4 * T0)
    assert stack.static_density(T0, P0, cx) == pytest.approx(rho0 * (T / T0) ** 2.5, rel=1e-12)


def test_working_point_meets_the_throttle(stack):
    for n, target in ((1.0, stack.exit_flow_des), (0.9, 1.01 * stack.exit_flow_des)):
        w, pr = stack.working_point(n, exit_flow=target)
        assert stack.exit_flow(w, n) == pytest.approx(target, rel=1e-9)
        assert stack.pressure_ratio(w, n) == pytest.approx(pr, rel=1e-12)


def test_margin_unchanged_when_the_throttle_follows_the_capacity(stack):
    """The mechanism: under uniform pure blockage f the speed line is the clean one scaled
    by (1 + f) in flow, so behind an exit flow scaled by the same (1 + f) the working point,
    the surge point and the margin are the clean ones; the margin rises only because the
    core takes more than that."""
    f = np.full(3, -0.02)
    for n in (1.0, 0.8):
        sm = stack.stall_margin(n, f, 0.98 * stack.exit_flow_des)
        assert sm == pytest.approx(stack.stall_margin(n), abs=1e-8)


def test_fouling_loss_lowers_the_surge_line(stack):
    """With k > 0 the deposit also lowers the stages' work and efficiency: the surge pressure
    ratio at constant speed falls, as fouling studies report, and the margin gain behind a
    fixed throttle shrinks."""
    lossy = StageStack(n_stages=3, pr_des=1.31, w_des=100.0, T_in=320.0, P_in=1.5e5,
                       fouling_loss=0.5)
    f_pure = stack.blockage_for_capacity(np.ones(3))
    f_lossy = lossy.blockage_for_capacity(np.ones(3))
    assert lossy.surge_point(1.0, f_lossy)[1] < lossy.surge_point(1.0)[1] - 1e-3
    gain_pure = stack.stall_margin(1.0, f_pure) - stack.stall_margin(1.0)
    gain_lossy = lossy.stall_margin(1.0, f_lossy) - lossy.stall_margin(1.0)
    assert 0.0 < gain_lossy < gain_pure


def test_choked_stack_and_unreachable_capacity_are_errors(stack):
    assert stack.run(3.0 * stack.w_des, 1.0) is None  # above the first stage's choking flux
    with pytest.raises(ValueError, match="choked"):
        stack.pressure_ratio(3.0 * stack.w_des, 1.0)
    with pytest.raises(ValueError, match="flow capacity"):
        stack.blockage_for_capacity(np.ones(3), -0.5)
