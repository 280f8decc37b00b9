"""The diagnosis's statistics: effective sample size, bounded fits and standard deviations that cover the
truth at the stated rate on band-limited (strongly autocorrelated) residuals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from identify.diagnose.statistics import block_ids, correlation_time, fit_bounded

FS, BAND = 500.0, 4.0


def _band_limited(rng: np.random.Generator, shape: tuple[int, ...], sigma: float) -> np.ndarray:
    sos = signal.butter(4, BAND, fs=FS, output="sos")
    return signal.sosfiltfilt(sos, rng.normal(0.0, sigma, shape), axis=0)


def _columns(n: int) -> np.ndarray:
    """(n, 2, 3) smooth columns in the band: a slow sine, a filtered square wave (Coulomb-like), a two-tone."""
    t = np.arange(n) / FS
    X = np.zeros((n, 2, 3))
    X[:, 0, 0] = np.sin(2 * np.pi * 0.3 * t)
    X[:, 0, 1] = np.sign(np.cos(2 * np.pi * 0.5 * t))
    X[:, 1, 2] = np.cos(2 * np.pi * 0.7 * t) + 0.3 * np.sin(2 * np.pi * 1.3 * t)
    return signal.sosfiltfilt(signal.butter(4, BAND, fs=FS, output="sos"), X, axis=0)


def test_correlation_time_of_white_noise_is_one_and_of_band_limited_noise_is_long() -> None:
    rng = np.random.default_rng(0)
    assert correlation_time(rng.normal(size=(20000, 2))) == pytest.approx(1.0, abs=0.2)
    # a 4 Hz band at 500 Hz: about one independent sample in sixty (the estimate)
    tau = correlation_time(_band_limited(rng, (20000, 2), 1.0))
    assert 40 < tau < 90


def test_blocks_never_straddle_records() -> None:
    record = np.repeat([0, 1, 2], [250, 130, 400])
    ids = block_ids(len(record), record, 100)
    for b in np.unique(ids):
        assert len(np.unique(record[ids == b])) == 1


@pytest.mark.slow
def test_stds_cover_the_truth_at_the_stated_rate_on_band_limited_data() -> None:
    """Monte Carlo: +-1 and +-2 std cover 68 % and 95 % of 400 fits on band-limited noise (binomial bands)."""
    n = 5000
    X = _columns(n)
    truth = np.array([0.1, 0.05, -0.2])
    z = []
    for seed in range(400):
        r = np.einsum("knp,p->kn", X, truth) + _band_limited(np.random.default_rng(seed), (n, 2), 0.05)
        fit = fit_bounded(X, r, np.ones(2))
        z.append((fit.coef - truth) / np.sqrt(np.diag(fit.cov)))
    z = np.abs(np.array(z))
    for k, rate in ((1.0, 0.683), (2.0, 0.954)):
        cover = np.mean(z < k, axis=0)
        band = 3 * np.sqrt(rate * (1 - rate) / len(z))
        assert np.all(cover > rate - band), (k, cover)
        assert np.all(cover < rate + band + 0.03), (k, cover)  # honest, not merely inflated


def test_white_noise_stds_are_not_inflated_needlessly() -> None:
    """On white noise the correlation time is ~1 and the std matches least squares' own."""
    rng = np.random.default_rng(1)
    X = rng.normal(size=(4000, 2, 2))
    r = np.einsum("knp,p->kn", X, [0.3, -0.1]) + rng.normal(0, 0.1, (4000, 2))
    fit = fit_bounded(X, r, np.ones(2))
    A = X.reshape(-1, 2)
    ols = 0.1**2 * np.linalg.inv(A.T @ A)
    assert np.sqrt(np.diag(fit.cov)) == pytest.approx(np.sqrt(np.diag(ols)), rel=0.15)


def test_a_fit_that_wants_to_leave_its_range_ends_at_the_bound_and_says_so() -> None:
    rng = np.random.default_rng(2)
    X = rng.normal(size=(2000, 1, 2))
    r = np.einsum("knp,p->kn", X, [-0.05, 0.2]) + rng.normal(0, 0.01, (2000, 1))
    fit = fit_bounded(X, r, np.ones(1), lower=np.array([0.0, -np.inf]))
    assert fit.coef[0] == pytest.approx(0.0, abs=1e-12)
    assert list(fit.bound_flags()) == [-1, 0]
    assert fit.cov[0, 0] == 0.0 and fit.cov[1, 1] > 0
    assert fit.coef[1] == pytest.approx(0.2, abs=0.01)


def test_cross_validation_leaves_a_held_out_records_own_nuisance_at_zero() -> None:
    """A per-record offset column touches only its record's rows: held out, that record's offset has no
    estimate and must not take the value the rounding residue of the fold's normal equations would give it
    (it did: held-out MSEs of 1e269 N^2 m^2, so record_offsets=true named nothing on real logs)."""
    from identify.diagnose.select import _scores

    rng = np.random.default_rng(0)
    n = 3000
    folds = np.repeat(np.arange(3), n // 3)
    x = rng.normal(size=n)
    offsets = np.column_stack([np.where(folds == f, 0.1, 0.0) for f in range(3)])
    A = np.column_stack([offsets, x])
    b = 0.7 * x + 0.3 * (folds == 0) + 0.01 * rng.normal(size=n)
    _, held = _scores(A, b, folds, 3, np.full(4, -np.inf), np.full(4, np.inf))
    # record 0's own offset (0.3) is unknown when it is held out: its error is that offset, the rest is noise
    assert held[0] == pytest.approx(0.09, rel=0.05)
    assert np.all(held[1:] < 2e-4)


def test_the_final_fit_weighs_each_joint_by_what_is_left_on_it() -> None:
    """A parameter shared by two joints, one of them with a large model error that its noise floor does not show
    (real logs: a floor of 0.01 N m under a residual of 0.13): weighting by the floor lets that joint decide the
    parameter; the final fit's feasible GLS weighs by what is left and recovers it from the other joint."""
    from types import SimpleNamespace

    from dynamics.plant import load_plant
    from identify.diagnose.diagnosis import _final_fit

    rng = np.random.default_rng(0)
    n, theta = 4000, 0.5
    x = rng.normal(size=(n, 2))
    structured = 0.3 + 0.5 * np.sin(np.linspace(0, 40, n))  # joint 0: a model error correlated with its column
    residual = theta * x + np.column_stack(
        [structured * x[:, 0] + 0.01 * rng.normal(size=n), 0.01 * rng.normal(size=n)]
    )
    X = x[:, :, None]
    s = SimpleNamespace(
        residual=residual,
        record=np.zeros(n, dtype=int),
        actuated=np.array([True, True]),
        used=None,  # every row used: the RMS per joint is the plain one
        used_rms=lambda x: np.sqrt(np.mean(x**2, axis=0)),
    )
    floor_weights = np.array([1e4, 1.0])  # the floor says joint 0 is the quiet one
    plant = load_plant("two_link")
    _, fit, _, _ = _final_fit(plant, [], X, s, floor_weights, n_nuisance=1)  # type: ignore[arg-type]
    naive = float(np.sum(floor_weights * x * residual) / np.sum(floor_weights * x * x))
    assert abs(naive - theta) > 0.05  # the floor-weighted estimate is pulled by joint 0's error
    assert abs(float(fit.coef[0]) - theta) < 0.01


def test_record_means_that_differ_are_named_and_band_limited_noise_is_not() -> None:
    """`changing_offsets`: each record's mean is judged against its own noise with its own autocorrelation time
    (band-limited residuals, 4 Hz at 500 Hz: about one independent sample in sixty). With no floor to hide
    behind, pure band-limited noise is named at about the stated rate (alpha = 1e-3: at most 3 of 400 joint
    tests), also when one record is short (its mean is not known well enough and it is left out) or has a
    narrower band; offsets of +-0.02 to 0.03 N m on one joint are named."""
    from identify.diagnose.residuals import changing_offsets

    rng = np.random.default_rng(0)
    n, records = 2000, 4
    names, actuated = ("a", "b"), np.array([True, True])
    no_floor = np.zeros(2)
    sources = [f"r{i}" for i in range(records)]

    def sets(lengths: list[int], narrow: int | None = None) -> int:
        record = np.concatenate([np.full(k, i) for i, k in enumerate(lengths)])
        hits = 0
        for _ in range(200):
            parts = [_band_limited(rng, (k, 2), 0.05) for k in lengths]
            if narrow is not None:
                sos = signal.butter(4, 1.0, fs=FS, output="sos")
                parts[narrow] = signal.sosfiltfilt(sos, rng.normal(0.0, 0.1, (lengths[narrow], 2)), axis=0)
            hits += len(changing_offsets(np.concatenate(parts), record, names, actuated, no_floor, sources))
        return hits

    assert sets([n] * records) <= 3
    assert sets([n, n, n, 80]) <= 3
    assert sets([n] * records, narrow=0) <= 3
    record = np.repeat(np.arange(records), n)
    e = np.concatenate([_band_limited(rng, (n, 2), 0.05) for _ in range(records)])
    e[:, 0] += np.repeat([0.03, -0.03, 0.02, -0.02], n)
    (found,) = changing_offsets(e, record, names, actuated, np.array([0.01, 0.01]), sources)
    assert found["joint"] == "a" and found["spread"] > 0.04
    assert changing_offsets(e[:n], record[:n], names, actuated, no_floor, sources[:1]) == []
    # a record named unusable for a joint (it never moves there) is left out of that joint's test
    assert (
        changing_offsets(e, record, names, actuated, no_floor, sources, exclude=frozenset({("r0", "a")}))[0]["sources"]
        == sources[1:]
    )


def test_a_record_whose_residual_is_constant_still_counts() -> None:
    """An exactly constant residual (a std of 0) has a known mean: it is compared, not a division by zero that
    turned every test into NaN and named nothing."""
    from identify.diagnose.residuals import changing_offsets

    e = np.concatenate([np.zeros((500, 1)), np.zeros((500, 1)), np.full((500, 1), 0.5)])
    record = np.repeat(np.arange(3), 500)
    with np.errstate(all="raise"):
        found = changing_offsets(e, record, ("a",), np.array([True]), np.array([0.01]), ["r0", "r1", "r2"])
    assert [f["joint"] for f in found] == ["a"]


def test_a_separation_without_a_rule_of_thumb_names_both_targets() -> None:
    """Two payloads on two bodies read 'the columns of payload and payload' before."""
    from identify.diagnose.diagnosis import _separation

    text = _separation("payload", "payload", "payload forearm_link", "payload upper_arm_link")
    assert "payload forearm_link and payload upper_arm_link differ" in text
    assert "swing past horizontal" in _separation("torque_offset", "rigid_body")


def test_a_finding_whose_joint_fit_z_is_below_the_floor_is_named_in_the_notes() -> None:
    """The selection judges each effect beside the ones chosen before it; the report fits them all together,
    where one may come out at |z| < 2.5 (a payload at 0.265 +- 0.107 kg on a UR5e): that is said, not hidden."""
    from identify.diagnose.diagnosis import Finding, _weak_findings

    def finding(effect: str, value: float, std: float, at_bound: str | None = None) -> Finding:
        null = 1.0 if effect == "torque_gain" else 0.0  # as `_findings` writes evidence["z"]
        z = (value - null) / std if std > 0 else float("nan")
        return Finding(effect, "elbow", value, std, "N m", "joint damping", {"z": z}, {}, at_bound=at_bound)

    weak = finding("payload", 0.265, 0.107)
    strong = finding("viscous_friction", 0.02, 0.001)
    gain = finding("torque_gain", 1.05, 0.01)  # |1.05 - 1| / 0.01 = 5
    bounded = finding("armature", 0.0, float("nan"), "lower")
    ((f, z),) = _weak_findings([weak, strong, gain, bounded], 2.5)
    assert f is weak and z == pytest.approx(2.477, abs=1e-3)


def _white(seed: int, n: int, std: float, nv: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, std, (n, nv))


def test_a_white_residual_larger_than_its_noise_is_structure() -> None:
    """A residual the Ljung-Box test takes for white can still hold more than the noise allows (a torque sensor's
    dead zone left three times the noise's share, and was `explained` by a torque gain of 0.92): its power in the
    band, beyond the noise's share, counts as structure."""
    from identify.diagnose.residuals import whiteness

    fs, floor = 500.0, np.array([0.05])
    x = _white(1, 20000, 3.5 * floor[0])  # white, 3.5 times the floor: 0.67 of the floor beyond it in the band
    (w,) = whiteness(x, floor, fs, band_hz=10.0)
    assert w["ljung_box_p"] > 0.01  # white: the correlation test alone passes it
    assert w["structured_rms"] > 0.5 * floor[0] and w["structured_rms"] > w["noise_in_band"]
    assert w["structured"]
    (w,) = whiteness(_white(0, 20000, floor[0]), floor, fs, band_hz=10.0)  # white at the floor: nothing
    assert not w["structured"] and w["structured_rms"] < 0.1 * floor[0]


def test_a_residual_mean_is_structure_unless_each_record_has_its_own_zero() -> None:
    """A torque zero the model does not have is structure: a test about the mean did not see 0.13 N m of it.
    Where each record's zero is its own (`own_zeros`: fitted per record), each record's mean is taken out."""
    from identify.diagnose.residuals import whiteness

    fs, floor = 500.0, np.array([0.05])
    x = _white(1, 5000, floor[0]) + 0.13
    (w,) = whiteness(x, floor, fs)
    assert w["structured"] and w["structured_rms"] == pytest.approx(0.13, rel=0.05)
    (w,) = whiteness(x, floor, fs, own_zeros=np.zeros(5000, int))
    assert not w["structured"]
    two = np.vstack([_white(5, 5000, floor[0]) + 0.05, _white(6, 5000, floor[0]) - 0.05])  # zeros of +-0.05
    records = np.repeat([0, 1], 5000)
    assert whiteness(two, floor, fs)[0]["structured"]
    assert not whiteness(two, floor, fs, own_zeros=records)[0]["structured"]


def test_the_angles_noise_in_the_model_torque_is_noise_not_structure() -> None:
    """Encoder noise differentiated twice reaches the model torque, in the band, where the torque sensor's floor
    does not count it: given a draw of it (`state_noise`), the same power in the residual is noise. The draw
    and the residual's noise are two samples of a coloured noise, whose powers differ by chance (by more than
    half the sensor's floor in a third of the records): over 40 of them none is called structure."""
    from identify.diagnose.residuals import whiteness

    fs, floor = 500.0, np.array([0.01])
    sos = signal.butter(4, 8.0, fs=fs, output="sos")
    for seed in range(0, 120, 3):
        states = signal.sosfiltfilt(sos, _white(seed, 5000, 0.2), axis=0)  # the angles' noise, in the band
        x = _white(seed + 1, 5000, floor[0]) + signal.sosfiltfilt(sos, _white(seed + 2, 5000, 0.2), axis=0)
        if seed == 0:
            assert whiteness(x, floor, fs)[0]["structured"]  # not counted, it is structure
        (w,) = whiteness(x, floor, fs, state_noise=states)
        assert not w["structured"], (seed, w)
    # a 1.3 Hz torque twice that noise's RMS on top of it is structure
    x = x + 2 * np.sqrt(2) * np.std(states) * np.sin(2 * np.pi * 1.3 * np.arange(5000) / fs)[:, None]
    assert whiteness(x, floor, fs, state_noise=states)[0]["structured"]


def test_an_effect_chosen_on_a_joint_takes_that_joints_other_variants_out_of_the_running() -> None:
    """Two Stribeck frictions of other speeds on the UR5e's elbow were both chosen (a damping and a frictionloss
    hidden there, another generator's data), and the calibrated MJCF could not be written: "repeated name
    'sysid_stribeck_friction_elbow_joint' in numeric". One value of an effect per joint or body; one friction shape
    per joint."""
    from dynamics.plant import load_plant
    from identify.diagnose.candidates import _shape_friction
    from identify.diagnose.select import Step, _taken

    plant = load_plant("two_link")
    shapes = _shape_friction(plant)
    stribeck = [c for c in shapes if c.effect == "stribeck_friction" and c.target == "elbow"]
    smooth = [c for c in shapes if c.effect == "smooth_coulomb_friction" and c.target == "elbow"]
    other_joint = [c for c in shapes if c.effect == "stribeck_friction" and c.target == "shoulder"]
    assert len(stribeck) > 1 and smooth and other_joint
    chosen = [Step(stribeck[0], np.arange(1), -10.0, 1.0, 0.5)]
    assert _taken(stribeck[1], chosen)  # another speed of the same effect on the same joint
    assert not _taken(other_joint[0], chosen) and not _taken(smooth[0], chosen)
    assert _taken(smooth[1], [Step(smooth[0], np.arange(1), -10.0, 1.0, 0.5)])  # one frictionloss per joint


def test_a_coefficient_that_changes_over_each_record_is_found_and_a_constant_one_is_not() -> None:
    """`changing_coefficient` on two 10 s records: a viscous friction constant in time is no change; one that grows
    from 0.005 to 0.035 N m s/rad over each record is found on dq with its start and end; a quadratic drag on a motion
    whose size grows fits a changing dq coefficient too, and the signature then says the motion's size changes."""
    from identify.diagnose.residuals import changing_coefficient, describe_signature

    rng = np.random.default_rng(0)
    t = np.arange(0.0, 10.0, 0.01)
    time, record = np.concatenate([t, t + 20.0]), np.repeat([0, 1], len(t))
    u = np.concatenate([t, t]) / t[-1]  # 0 to 1 over each record
    dq = np.sin(2 * np.pi * 0.7 * time) + 0.5 * np.sin(2 * np.pi * 1.3 * time + 1.0)
    probes = {"q": np.cos(time), "dq": dq, "sign_dq": np.sign(dq), "ddq": np.cos(3 * time)}
    noise = 0.002 * rng.normal(size=len(time))
    assert changing_coefficient(0.02 * dq + noise, probes, record, time) is None
    change = changing_coefficient((0.005 + 0.03 * u) * dq + noise, probes, record, time)
    assert change is not None and change["probe"] == "dq", change
    assert change["start"] == pytest.approx(0.005, abs=5e-4) and change["end"] == pytest.approx(0.035, abs=5e-4)
    assert 1 / 1.5 < change["motion_ratio"] < 1.5
    # a quadratic drag on a motion whose size grows sixfold: a growing sign(dq) coefficient fits a sixth of it, but
    # leaves most of what a constant one leaves: no drift is claimed
    growing = (0.3 + 1.4 * u) * dq
    drag = 0.05 * growing * np.abs(growing) + noise
    assert changing_coefficient(drag, {**probes, "dq": growing, "sign_dq": np.sign(growing)}, record, time) is None
    signature = {"correlation": {}, "position_periodic": {"share": 0.0}, "rms_over_noise": 5.0}
    text = describe_signature({"elbow": {**signature, "changes_over_time": {**change, "motion_ratio": 2.0}}})
    assert "from 0.00485 to 0.0351 N m s/rad (the joint's speed changes over the records too (x 2 from" in text, text


def test_structure_below_the_verdicts_effect_size_is_said_not_hidden() -> None:
    """A residual the Ljung-Box test finds structured, with more than the noise in the band but below half the
    noise floor, passes the verdict as white (an out-of-vocabulary position-dependent viscous friction was
    `explained` by a plain one so, 2.3 times the in-band noise, p 0.001); it is said in a note. White noise, a
    residual the test does not reject, and structure the verdict already counts are not."""
    from identify.diagnose.diagnosis import _weak_structure_notes
    from identify.diagnose.residuals import whiteness

    fs, n = 400.0, 6000
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    noise = rng.normal(0.0, 0.034, (n, 4))
    slow = np.sin(2 * np.pi * 0.7 * t)
    residual = noise + np.column_stack([0.0126 * np.sqrt(2) * slow, 0 * t, 0.004 * np.sqrt(2) * slow, 0.3 * slow])
    white = whiteness(residual, np.full(4, 0.034), fs)
    assert [w["weak"] for w in white] == [True, False, False, False], white  # white noise, too little, counted
    assert white[3]["structured"] and white[0]["effect_size"] == pytest.approx(0.017)
    notes = _weak_structure_notes(["a", "b", "c", "d"], white)
    assert len(notes) == 1 and notes[0].startswith("a: the residual left holds 0.01"), notes
    assert "times the noise in the band (Ljung-Box p = " in notes[0] and "(0.017 N m, half the noise floor)" in notes[0]
