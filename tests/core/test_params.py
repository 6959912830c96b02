"""Parameter dataclasses, YAML (plain and ROS 2 layout), whole-set validation."""

from dataclasses import replace
from pathlib import Path

from ladrc_follow.control.params import (
    EXTRA_VALIDATORS,
    ControllerParams,
    ESOParams,
    FollowParams,
    LawParams,
    LimitParams,
    ParameterError,
    check,
    dump_params,
    load_params,
    params_from_dict,
    params_to_dict,
    validate,
)
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / 'ros2_ws' / 'src' / 'ladrc_bringup' / 'config' / 'follow.yaml'


def test_defaults_are_valid_and_seed_faithful():
    p = ControllerParams()
    assert validate(p) == []
    assert (p.eso.order, p.eso.betas, p.eso.b0, p.law.kp) == (1, (180.0, 10800.0), 1.0, 10.0)
    assert (p.td_b.k1, p.td_b.k2, p.td_b.r_per_s, p.td_b.alpha) == (1.2, 4.0, 100.0, 0.0)
    assert p.h_s == 0.0005


def test_shipped_file_loads_and_equals_defaults():
    raw = yaml.safe_load(SHIPPED.read_text())
    assert 'ros__parameters' in raw['/**']  # applies to any node name or namespace
    assert load_params(SHIPPED) == ControllerParams()


@pytest.mark.parametrize('ros_node', [None, 'ladrc_follow'])
def test_yaml_round_trip(tmp_path, ros_node):
    p = ControllerParams(eso=ESOParams(order=2, discretization='zoh', gains='bandwidth',
                                       w0_rad_s=200.0, b0=125.0, compensator=True),
                         law=LawParams(form=1, gains='bandwidth', wc_rad_s=30.0),
                         follow=FollowParams(locking_timeout_s=0.2, controller='pid'))
    path = tmp_path / 'p.yaml'
    path.write_text(dump_params(p, ros_node=ros_node))
    assert load_params(path) == p
    assert params_from_dict(params_to_dict(p)) == p


def test_ros_dotted_keys_and_wildcard():
    d = {'/**': {'ros__parameters': {'eso.b0': 2.0, 'law.kp': 12.0, 'limits':
                                     {'v_max_mm_s': 150.0}}}}
    p = params_from_dict(d)
    assert (p.eso.b0, p.law.kp) == (2.0, 12.0)
    p = params_from_dict({'ladrc_follow': {'ros__parameters': {'eso': {'b0': 3}}}},
                         node_name='ladrc_follow')
    assert p.eso.b0 == 3.0 and isinstance(p.eso.b0, float)


def has(reasons_: list[str], prefix: str) -> bool:
    return any(m.startswith(prefix) for m in reasons_)


def reasons(**sections):
    return validate(replace(ControllerParams(), **sections))


def test_b0_zero():
    assert has(reasons(eso=ESOParams(b0=0.0)),
               'eso.b0 = 0: outside its range [0.01, 100000] order 1: 1; order 2: 1/s')


def test_w0_must_be_positive():
    r = reasons(eso=ESOParams(gains='bandwidth', w0_rad_s=0.0))
    assert has(r, 'eso.w0_rad_s = 0: outside its range (0, 20000] rad/s')


def test_unstable_euler_observer_reports_bound():
    # bandwidth gains: explicit Euler error poles at 1 − ω0·h → unstable beyond ω0·h = 2
    r = reasons(eso=ESOParams(order=2, gains='bandwidth', w0_rad_s=4400.0, b0=100.0),
                law=LawParams(kp=400.0, kd=40.0))
    assert any(m.startswith('eso: explicit-Euler observer with ω0·h = 2.2 is unstable '
                            '(bound 2.000 for order 2)') for m in r), r
    # explicit betas: poles −4000 ± j2828, Euler needs h < 2·4000/2.4e7 = 0.33 ms
    r = reasons(eso=ESOParams(betas=(8000.0, 2.4e7)))
    assert any('explicit-Euler observer with betas [8000.0, 24000000.0] at h = 0.0005 s is '
               'unstable' in m for m in r), r


def test_betas_count_and_zoh_needs_w0():
    assert 'eso.betas needs 3 values for order 2, got 2' in reasons(
        eso=ESOParams(order=2), law=LawParams(kp=100.0, kd=20.0))
    r = reasons(eso=ESOParams(discretization='zoh'))
    assert any("'zoh' discretization derives its gains" in m for m in r)


def test_limit_contradiction():
    r = reasons(limits=LimitParams(v_max_mm_s=50.0, a_max_mm_s2=4000.0))
    assert any(m.startswith('limits.v_max_mm_s (50) below pid.v_max_mm_s (150)')
               and 'contradiction' in m for m in r), r
    assert any(m.startswith('limits.v_max_mm_s (50) below interp.v_max_mm_s (60)')
               for m in r), r


def test_law_problems():
    assert has(reasons(law=LawParams(form=4)), 'law.form = 4: must be one of 1, 2, 3')
    assert 'law.kd must be > 0 for the order-2 law, got 0.0' in reasons(
        eso=ESOParams(order=2, betas=(300.0, 3e4, 1e6), b0=100.0), law=LawParams(kp=100.0))
    assert any('kp·h = 1.5 >= 1' in m for m in reasons(law=LawParams(kp=3000.0)))


def test_td_and_kalman_problems_are_prefixed():
    p = ControllerParams()
    r = reasons(td_b=replace(p.td_b, k2=-1.0), kalman=replace(p.kalman, r_mm2=0.0))
    assert has(r, 'td_b.k2 = -1: outside its range (0, 1000]')
    assert has(r, 'kalman.r_mm2 = 0: outside its range (0, 100] mm²')


def test_every_reason_reported_at_once():
    with pytest.raises(ParameterError) as exc:
        check(replace(ControllerParams(), eso=ESOParams(b0=0.0), law=LawParams(kp=-1.0)))
    assert len(exc.value.reasons) == 2
    assert 'eso.b0 = 0' in str(exc.value) and 'law.kp = -1' in str(exc.value)


def test_unknown_and_mistyped_keys():
    with pytest.raises(ParameterError) as exc:
        params_from_dict({'eso': {'bandwith': 3.0, 'b0': 'one'}, 'lawz': {}})
    msg = str(exc.value)
    assert "unknown key 'eso.bandwith'" in msg
    assert "unknown key 'lawz'" in msg
    assert "eso.b0 = 'one': must be a number" in msg


def test_extra_validators_hook():
    def no_follow_x(p):
        return ['follow.retarget_threshold_mm must be 2'] if (
            p.follow.retarget_threshold_mm != 2.0) else []
    EXTRA_VALIDATORS.append(no_follow_x)
    try:
        assert 'follow.retarget_threshold_mm must be 2' in validate(ControllerParams())
        assert validate(ControllerParams(follow=FollowParams(retarget_threshold_mm=2.0))) == []
    finally:
        EXTRA_VALIDATORS.remove(no_follow_x)


def test_load_errors(tmp_path):
    with pytest.raises(ParameterError, match='cannot read parameter file'):
        load_params(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('eso: [1, 2\n')
    with pytest.raises(ParameterError, match='not valid YAML'):
        load_params(bad)


def test_follow_section_is_typed_and_validated_with_the_set():
    p = params_from_dict({'follow': {'controller': 'pid', 'collision_gap_mm': 0.1}})
    assert p.follow == FollowParams(controller='pid', collision_gap_mm=0.1)
    with pytest.raises(ParameterError) as err:
        params_from_dict({'follow': {'collision_gap_mm': 0.5, 'min_target_gap_mm': 0.4}})
    assert 'collision_gap_mm (0.5) must be below min_target_gap_mm (0.4)' in str(err.value)
    with pytest.raises(ParameterError) as err:
        params_from_dict({'follow': {'stale_timeout_s': 0.0001}})
    assert 'stale_timeout_s' in str(err.value)
    with pytest.raises(ParameterError) as err:
        params_from_dict({'follow': {'controler': 'pid'}})
    assert "unknown key 'follow.controler'" in str(err.value)


def test_an_order2_loop_faster_than_the_sampling_is_rejected():
    r = reasons(eso=ESOParams(order=2, gains='bandwidth', w0_rad_s=600.0, b0=125.0),
                law=LawParams(gains='bandwidth', wc_rad_s=2000.0))
    assert any(m.startswith('law: the order-2 loop poles reach 2000 rad/s') for m in r), r
    assert reasons(eso=ESOParams(order=2, gains='bandwidth', w0_rad_s=600.0, b0=125.0),
                   law=LawParams(gains='bandwidth', wc_rad_s=100.0)) == []
