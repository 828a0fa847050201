"""One identification framework (docs/estimation.md, "Architecture: one identification framework"): one loader,
one set of transforms, one standard-error implementation, one temperature pre-processing module, one estimator
interface.

The structural checks read the source (an AST walk): the diagnosis modules import these pieces from
their one owner and define no second copy."""

from __future__ import annotations

import ast
import functools
import math
from importlib import import_module
from pathlib import Path

import numpy as np
import pytest

from valve_env.experiment import simulate_experiment
from valve_env.ident import sde as model
from valve_env.ident import uncertainty as covariance
from valve_env.ident.mle import Estimator, MLEstimator
from valve_env.valveid import temperature
from valve_env.valveid.estimator import ValveEstimator
from valve_env.valveid.fitting import Model

PKG = Path(__file__).resolve().parents[2] / "valve_env"
#: the valve layer's modules of the diagnosis (forward selection, the output-error model and engine)
DIAGNOSIS = tuple(f"valveid/{m}.py" for m in ("diagnose", "effects", "fitting", "sde_effects", "stiction", "report",
                                               "cli", "bench", "oe", "__init__"))

#: each shared piece, its one owner, and the names no other module of the package may define
OWNERS: dict[str, tuple[str, ...]] = {
    "ident/sde.py": ("to_work", "from_work", "dnat_dwork", "work_bounds"),
    "ident/uncertainty.py": ("fd_hessian", "identified_directions", "identified_inverse", "_identified_inverse",
                                 "hac_meat", "score_matrix", "hessian_sandwich_sd", "robust_std", "step_nll",
                                 "score_contributions"),
    "valveid/temperature.py": ("smooth_temperature", "_irw_pass", "tv_denoise", "relaxed_tv",
                                  "denoise_temperature", "noise_sd"),
    "data_io.py": ("load_run", "validate_run"),
    "valveid/data.py": ("RunData",),
    "valveid/bootstrap.py": ("bootstrap", "apply_bootstrap", "BootstrapResult", "replicate_run", "world_opening",
                             "denoised_run", "bracketed", "preprocessing_refit"),
    "ident/bootstrap.py": ("replicates", "residual_block_length", "block_resample", "gross_refits", "screen_refits"),
    "ident/tests.py": ("lr_pvalue", "delta_bic", "ljung_box", "residual_report", "cumulated_periodogram",
                       "whiteness_check", "misspecification_check", "lr_test"),
    "valveid/robust.py": ("sandwich_std", "effect_misspecification", "robust_finding"),
}
#: a method of this name may exist elsewhere only as a thin wrapper that calls the owner's function
WRAPPERS = {"to_work", "from_work", "work_bounds", "noise_sd", "bootstrap"}


@functools.cache  # parsed once: the checks walk every module once per owner (read only)
def _tree(rel: str) -> ast.Module:
    return ast.parse((PKG / rel).read_text(encoding="utf-8"))


def _modules() -> list[str]:
    return sorted(str(p.relative_to(PKG)) for p in PKG.rglob("*.py"))


@functools.cache  # per parsed module (the trees are cached)
def _definitions(tree: ast.Module) -> list[ast.FunctionDef | ast.ClassDef | ast.AsyncFunctionDef]:
    return [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))]


def _calls(node: ast.AST) -> set[str]:
    out = set()
    for n in ast.walk(node):
        if isinstance(n, ast.Call):
            f = n.func
            out.add(f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else "")
    return out


def _import_origins(tree: ast.Module) -> dict[str, tuple[str, str]]:
    """imported name (as bound) -> (module, name there)"""
    return {a.asname or a.name: (n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
            and n.module for a in n.names}


def _imports(tree: ast.Module) -> dict[str, str]:
    """imported name -> module it comes from"""
    out = {}
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom) and n.module:
            for a in n.names:
                out[a.asname or a.name] = n.module
    return out


def test_no_second_copy_of_a_shared_piece_is_defined() -> None:
    """No module but the owner defines a loader, a transform, a standard error or a smoother (a
    same-named method that only delegates to the owner's function is allowed)."""
    for owner, names in OWNERS.items():
        for rel in _modules():
            if rel == owner:
                continue
            for d in _definitions(_tree(rel)):
                if d.name not in names:
                    continue
                if d.name in WRAPPERS and isinstance(d, ast.FunctionDef):
                    owner_mod = import_module("valve_env." + owner[:-3].replace("/", "."))
                    origin = _import_origins(_tree(rel))
                    delegates = any(c in origin and getattr(import_module(origin[c][0]), origin[c][1], None)
                                    is getattr(owner_mod, origin[c][1], ()) for c in _calls(d))
                    assert delegates, f"{rel}: {d.name} does not delegate to valve_env/{owner}"
                    continue
                pytest.fail(f"{rel} defines {d.name}, which valve_env/{owner} owns")


def test_the_diagnosis_imports_the_shared_pieces_from_their_owner() -> None:
    fitting = _imports(_tree("valveid/fitting.py"))
    for name in ("to_work", "from_work", "dnat_dwork", "work_bounds", "Parameter"):
        assert fitting.get(name) == "valve_env.ident.sde", name
    assert fitting.get("hessian_sandwich_parts") == "valve_env.ident.uncertainty"
    assert fitting.get("RunData") == "valve_env.valveid.data"
    assert _imports(_tree("valveid/data.py")).get("smooth_temperature") == "valve_env.valveid.temperature"
    diagnose = _imports(_tree("valveid/diagnose.py"))
    assert diagnose.get("load_run") == diagnose.get("validate_run") == "valve_env.data_io"
    assert _imports(_tree("ident/mle.py")).get("identified_directions") == "valve_env.ident.uncertainty"
    # no module of the diagnosis inverts a Hessian, computes a HAC meat or reads a CSV itself
    for rel in _modules():
        if rel not in DIAGNOSIS:
            continue
        src = (PKG / rel).read_text(encoding="utf-8")
        for banned in ("np.linalg.inv(", "np.linalg.pinv(", "np.linalg.eigh(", "S_hac", "read_csv("):
            assert banned not in src, f"{rel} uses {banned}"


def test_only_the_loader_reads_a_run_csv() -> None:
    """pandas.read_csv appears only in the loader (and in the packaged tapping-profile table)."""
    readers = sorted(rel for rel in _modules() if "read_csv(" in (PKG / rel).read_text(encoding="utf-8"))
    assert readers == ["data_io.py", "scenario.py"]


def test_the_diagnosis_parameters_are_the_estimation_parameters() -> None:
    m = Model(("medium_temperature", "sensor_lag"))
    assert all(isinstance(q, model.Parameter) for q in m.parameters)
    values = {q.name: (q.lower * q.upper) ** 0.5 if q.transform == "log" else 0.5 * q.upper for q in m.parameters}
    z = m.to_work(values)
    assert z.tolist() == [model.to_work(values[q.name], q) for q in m.parameters]
    back = m.from_work(z)
    assert all(math.isclose(back[k], v, rel_tol=1e-12) for k, v in values.items())
    # a scaled linear parameter: value / scale on the optimiser's side
    beta = m.parameters[m.names.index("beta")]
    assert beta.transform == "none" and model.to_work(0.2, beta) == pytest.approx(0.2 / beta.scale)


def test_identified_inverse_drops_a_direction_the_box_constrains_better() -> None:
    """A direction whose +-1 sd interval is wider than the parameter box is held fixed (not inverted);
    the other is the plain inverse."""
    H = np.diag([1.0e4, 1.0e-2])  # sd 0.01 and 10 on the work scale
    inv = covariance.identified_inverse(H, [5.0, 5.0])
    assert inv is not None
    assert inv[0, 0] == pytest.approx(1.0e-4) and inv[1, 1] == 0.0
    assert np.allclose(covariance.identified_inverse(H, [5.0, 100.0]), np.linalg.inv(H))
    assert np.allclose(covariance.identified_inverse(H, None), np.linalg.inv(H))
    assert covariance.identified_inverse(np.diag([-1.0, 0.0]), None) is None


def test_hac_meat_is_newey_west() -> None:
    rng = np.random.default_rng(0)
    G = rng.standard_normal((400, 2))
    G[1:] += 0.8 * G[:-1]
    M = covariance.hac_meat(G)
    Gc = G - G.mean(axis=0)
    L = int(4.0 * (400 / 100.0) ** (2.0 / 9.0))
    ref = Gc.T @ Gc
    for lag in range(1, L + 1):
        S = Gc[lag:].T @ Gc[:-lag]
        ref += (1.0 - lag / (L + 1.0)) * (S + S.T)
    assert np.allclose(M, ref)


def test_one_temperature_module_serves_both_likelihoods() -> None:
    """The EKF's inputs (TV) and the output error's latent temperatures (IRW-RTS) both come from
    valve_env.valveid.temperature; each is closer to the truth than the raw channel."""
    from valve_env.valveid.data import RunData
    from valve_env.valveid.valve_model import prepare_inputs

    df = simulate_experiment(seed=3, duration_h=3.0, dt_s=10.0, T_noise_C=0.01)
    truth = df["true_T_tank_C"].to_numpy()
    raw = float(np.sqrt(np.mean((df["T_tank_C"].to_numpy() - truth) ** 2)))
    tv = prepare_inputs(df)["T_tank_s"].to_numpy()
    assert np.array_equal(tv, temperature.denoise_temperature(df["T_tank_C"].to_numpy(), df["time_s"].to_numpy())[0])
    irw = RunData.from_frame(df).T
    for level in (tv, irw):
        assert float(np.sqrt(np.mean((level - truth) ** 2))) < 0.8 * raw


def test_both_estimators_share_the_interface() -> None:
    assert issubclass(MLEstimator, Estimator) and issubclass(ValveEstimator, Estimator)
    with pytest.raises(ValueError, match="unknown likelihood"):
        ValveEstimator(likelihood="nope")
    with pytest.raises(ValueError, match="unknown effect"):
        ValveEstimator(("nope",))


def test_valve_estimator_wraps_each_likelihood_without_changing_its_numbers() -> None:
    """fit returns self with the back-end's own numbers, for the EKF and for the output error."""
    from valve_env.valveid.data import RunData
    from valve_env.valveid.valve_model import base_valve_model

    df = simulate_experiment(seed=11, duration_h=4.0, dt_s=20.0, T_noise_C=0.005, x_noise_mm=2.0e-3)
    ekf = ValveEstimator(n_starts=1, hessian=False)
    assert ekf.fit(df) is ekf
    ref = MLEstimator(base_valve_model(), n_starts=1, hessian=False).fit(df)
    assert ekf.params_ == ref.params_ and ekf.loglik_ == ref.loglik_ and ekf.n_free_ == ref.n_free_
    oe = ValveEstimator(likelihood="output_error", with_std=False).fit(df)
    res = Model(()).fit(RunData.from_frame(df), with_std=False)
    assert oe.params_ == res.params and oe.loglik_ == res.loglik
    assert oe.n_free_ == res.n_free == 6 and oe.aic_ == pytest.approx(-2.0 * res.loglik + 12.0)
    assert abs(oe.params_["sigma"] / ekf.params_["sigma"] - 1.0) < 0.1  # the two likelihoods agree on sigma
    assert list(oe.summary().index) == list(oe.params_)


def test_one_hac_meat_serves_both_sandwiches() -> None:
    """The HAC meat has one home (covariance.hac_meat): the EKF's sandwich (covariance.robust_std) and the
    output error's (covariance.hessian_sandwich_parts) both take it; no other module calls statsmodels'
    S_hac_simple, and the valve's fit takes both sandwiches from the core."""
    users = sorted(rel for rel in _modules() if "S_hac" in (PKG / rel).read_text(encoding="utf-8"))
    assert users == ["ident/uncertainty.py"]
    assert _imports(_tree("valveid/fitting.py")).get("hessian_sandwich_parts") == "valve_env.ident.uncertainty"
    assert _imports(_tree("valveid/fit.py")).get("robust_std") == "valve_env.ident.uncertainty"
    rng = np.random.default_rng(1)
    G = rng.standard_normal((300, 3)) + 0.3
    assert np.array_equal(covariance.hac_meat(G, 0, demean=False), G.T @ G)  # Huber-White's outer product
    Gc = G - G.mean(axis=0)
    assert np.allclose(covariance.hac_meat(G, 0), Gc.T @ Gc)
    assert not np.allclose(covariance.hac_meat(G, 3), covariance.hac_meat(G, 3, demean=False))


def test_the_diagnosis_fits_and_bootstraps_through_the_estimator() -> None:
    """diagnose.py makes every fit with ValveEstimator(...).fit(...) and reaches the bootstrap through
    the estimator's bootstrap method (the estimation's facility), not by calling the diagnosis's
    fitting.Model or the bootstrap function itself."""
    tree = _tree("valveid/diagnose.py")
    imports = _imports(tree)
    assert imports.get("ValveEstimator") == "valve_env.valveid.estimator"
    assert "bootstrap" not in imports
    fits = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
            and n.func.attr == "fit"]
    assert fits
    for n in fits:
        inner = n.func.value  # type: ignore[attr-defined]
        assert isinstance(inner, ast.Call) and getattr(inner.func, "id", None) == "ValveEstimator", ast.unparse(n)
    calls = _calls(tree)
    assert "bootstrap" in calls and "apply_bootstrap" not in calls


def test_the_bootstrap_has_one_home_in_the_estimation() -> None:
    """The bootstrap (a standard error) lives in valve_env/valveid/bootstrap.py, the named effects' sandwich
    and misspecification check in estimation/robust.py: the diagnosis imports them from there, keeps no module
    of its own for them, and does no resampling, robust scale or normality test itself."""

    assert not (PKG / "valveid" / "uncertainty.py").exists()
    diagnose = _imports(_tree("valveid/diagnose.py"))
    assert diagnose.get("METHOD") == "valve_env.valveid.bootstrap"
    assert diagnose.get("NORMAL_P") == "valve_env.ident.bootstrap"
    assert diagnose.get("robust_finding") == "valve_env.valveid.robust"
    estimator = _imports(_tree("valveid/estimator.py"))
    assert estimator.get("bootstrap") == estimator.get("apply_bootstrap") == "valve_env.valveid.bootstrap"
    for rel in _modules():
        if rel in DIAGNOSIS:
            imported = _imports(_tree(rel))
            assert not any(m.endswith("valveid.uncertainty") for m in imported.values()), rel
            src = (PKG / rel).read_text(encoding="utf-8")
            for banned in ("optimal_block_length(", "qn_scale(", "shapiro(", "block_resample(", "whiteness_check("):
                assert banned not in src, f"{rel} uses {banned}"


def test_valve_estimator_takes_the_framework_container() -> None:
    """A prepared RunData (e.g. a training slice) is an input of the output-error estimator, with the
    same numbers as the DataFrame it came from; the EKF refuses it."""
    from valve_env.valveid.data import RunData

    df = simulate_experiment(seed=12, duration_h=3.0, dt_s=20.0, T_noise_C=0.005, x_noise_mm=2.0e-3)
    a = ValveEstimator(likelihood="output_error", with_std=False).fit(df)
    run = RunData.from_frame(df)
    b = ValveEstimator(likelihood="output_error", with_std=False).fit(run)
    assert a.params_ == b.params_ and a.loglik_ == b.loglik_ and b.data_ is run
    with pytest.raises(ValueError, match="output_error"):
        ValveEstimator().fit(run)
    with pytest.raises(ValueError, match="output_error"):
        ValveEstimator(n_starts=1, hessian=False).fit(df).bootstrap(2)


@pytest.mark.slow
def test_valve_estimator_bootstrap_is_the_diagnosis_bootstrap() -> None:
    """fit(...).bootstrap(B) returns self and sets what the diagnosis reports for a named effect: the
    TV refit's estimate (the pre-processing bracket), the sd at least the inverse Hessian's and at
    least half the IRW-TV difference; without effects it bootstraps the base parameters, unbracketed."""
    from valve_env.valveid import bootstrap as uncertainty
    from valve_env.valveid.data import RunData

    df = simulate_experiment(seed=5, duration_h=4.0, dt_s=20.0, effects={"sensor_lag": {"tau_s": 60.0}},
                             T_noise_C=0.005, x_noise_mm=2.0e-3)
    run = RunData.from_frame(df)
    est = ValveEstimator(("sensor_lag",), likelihood="output_error").fit(run)
    irw, sd_h = est.params_["tau_s"], est.std_["tau_s"]
    assert est.bootstrap(3) is est
    assert est.bootstrap_.B == 3 and est.bootstrap_.names == ["tau_s"]
    assert est.std_from_["tau_s"].endswith("+bracket")
    tv = est.result_.extra["tv_tau_s"]
    assert est.params_["tau_s"] == tv and est.result_.extra["irw_tau_s"] == irw
    assert est.std_["tau_s"] >= max(sd_h, 0.5 * abs(tv - irw))
    refit = uncertainty.preprocessing_refit(est.backend_, run, est.result_, ["tau_s"])
    assert math.isfinite(refit["tau_s"]) and abs(refit["tau_s"] / 60.0 - 1.0) < 0.1
    base = ValveEstimator(likelihood="output_error").fit(run.slice(0, 400)).bootstrap(2)
    assert base.bootstrap_.names == ["sigma", "F_hmax", "p_bset"]
    assert all(not s.endswith("+bracket") for s in base.std_from_.values())
