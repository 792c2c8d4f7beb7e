"""The interaction pipeline reproduces the `phasekit` command's numbers on the same model file.

Needs the command: `PHASEKIT_BIN`, or `target/{debug,release}/phasekit` of this
repository (scripts/test.sh builds it and sets PHASEKIT_BIN).
"""

import json
import os
import pickle
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from phasekit import InteractionModel, datasets

ROOT = Path(__file__).resolve().parents[2]
COLUMNS = ["p1_wrist_x", "p1_wrist_y", "p1_wrist_z", "p2_wrist_x", "p2_wrist_y", "p2_wrist_z"]


def phasekit_bin():
    env = os.environ.get("PHASEKIT_BIN")
    if env:
        assert Path(env).is_file(), f"PHASEKIT_BIN={env} does not exist"
        return env
    for profile in ("debug", "release"):
        p = ROOT / "target" / profile / "phasekit"
        if p.is_file():
            return str(p)
    found = shutil.which("phasekit")
    if found:
        return found
    pytest.skip("the phasekit command is not built (cargo build -p phasekit-cli, or set PHASEKIT_BIN)")


def demo(rng, n):
    """A handshake-like demonstration: the human reaches, shakes, retracts; the robot mirrors."""
    t = np.linspace(0, 1, n)
    reach = np.clip(t * 3, 0, 1) - np.clip((t - 0.7) * 3.3, 0, 1)
    shake = np.where((t > 0.33) & (t < 0.7), 0.05 * np.sin(40 * t), 0)
    human = np.stack([0.3 * reach, 0.02 * np.sin(3 * t), 0.25 * reach + shake], axis=1)
    robot = human * [1.05, -1.0, 0.95] + [0.02, 0.0, 0.01]
    return np.hstack([human, robot]) + rng.normal(scale=0.005, size=(n, 6))


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("demos")
    rng = np.random.default_rng(0)
    for k in range(6):
        data = demo(rng, int(rng.integers(90, 130)))
        np.savetxt(d / f"train_{k:02d}.csv", data, delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.17g")
    np.savetxt(d / "test_00.csv", demo(rng, 110), delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.17g")
    return d


def run(*args, stdin=None):
    out = subprocess.run([phasekit_bin(), *map(str, args)], input=stdin, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout


def read_csv(path_or_text):
    text = Path(path_or_text).read_text() if isinstance(path_or_text, Path) else path_or_text
    lines = [l for l in text.strip().splitlines() if l]
    header = lines[0].split(",")
    rows = [l.split(",") for l in lines[1:]]
    return header, rows


def test_python_reproduces_the_command_on_its_model_file(folder, tmp_path):
    model_file = tmp_path / "cli.json"
    run("fit", "--data", folder, "--method", "hmm", "-o", model_file)
    model = InteractionModel.load(model_file)
    test = folder / "test_00.csv"
    # predict: the command's CSV prints every number in its shortest round-trip form
    run("predict", "--model", model_file, "--data", test, "--covariance", "-o", tmp_path / "pred.csv")
    header, rows = read_csv(tmp_path / "pred.csv")
    cli = np.array([[float(v) for v in r[1:]] for r in rows])
    demo_ = datasets.read_demonstration(test)
    p = model.predict(demo_)
    o = len(model.robot_features)
    assert header[1 : 1 + o] == model.robot_features
    np.testing.assert_array_equal(p.mean, cli[:, :o])
    iu = np.triu_indices(o)
    np.testing.assert_array_equal(p.covariance[:, iu[0], iu[1]], cli[:, o:])
    # segment
    run("segment", "--model", model_file, "--data", test, "-o", tmp_path / "seg.csv")
    _, rows = read_csv(tmp_path / "seg.csv")
    seg = model.segment(demo_)
    np.testing.assert_array_equal(seg.states, [int(r[2]) for r in rows])
    np.testing.assert_array_equal(seg.transitions, [int(r[1]) for r in rows if r[3] == "1"])
    # stream (online): the human's columns one line at a time
    human = demo_.values[:, :3]
    lines = "\n".join(",".join(repr(float(v)) for v in row) for row in human) + "\n"
    header, rows = read_csv(run("stream", "--model", model_file, stdin=lines))
    # The stream's columns by name: the robot's predicted features (the status
    # column says whether the frame was read as given).
    idx = [header.index(name) for name in model.robot_features]
    assert "status" in header and all(r[header.index("status")] == "ok" for r in rows)
    cli = np.array([[float(r[i]) for i in idx] for r in rows])
    online = model.online()
    ours = np.array([online.step(f) for f in human])
    np.testing.assert_array_equal(ours, cli)
    np.testing.assert_array_equal(ours, p.mean)  # online = batch, frame by frame


def test_autos_calibration_reaches_python_batch_and_online(folder, tmp_path):
    # `auto` calibrates its covariance (the held-out errors' covariance added,
    # then a factor): Python's batch and online predictions carry it exactly
    # as the command's, and differ from the uncalibrated model's bands only.
    files = {}
    for name, spec in [("on", "auto:grid=small,folds=3"), ("off", "auto:grid=small,folds=3,calibrate=off")]:
        files[name] = tmp_path / f"{name}.json"
        run("fit", "--data", folder, "--method", spec, "-o", files[name])
    cal = json.loads(files["on"].read_text())["fit"]["covariance_calibration"]
    assert cal["residual_weight"] > 0 and len(cal["added_covariance"]) > 0
    test = folder / "test_00.csv"
    run("predict", "--model", files["on"], "--data", test, "--covariance", "-o", tmp_path / "pred.csv")
    _, rows = read_csv(tmp_path / "pred.csv")
    cli = np.array([[float(v) for v in r[1:]] for r in rows])
    on, off = InteractionModel.load(files["on"]), InteractionModel.load(files["off"])
    demo_ = datasets.read_demonstration(test)
    p, q = on.predict(demo_), off.predict(demo_)
    o = len(on.robot_features)
    iu = np.triu_indices(o)
    np.testing.assert_array_equal(p.mean, cli[:, :o])
    np.testing.assert_array_equal(p.covariance[:, iu[0], iu[1]], cli[:, o:])
    np.testing.assert_array_equal(p.mean, q.mean)
    added = np.array(cal["added_covariance"]).reshape(o, o)
    np.testing.assert_allclose(p.covariance, (q.covariance + added) * cal["scale"], rtol=1e-12)
    online = on.online()
    for t, frame in enumerate(demo_.values[:, :3]):
        mean, cov = online.step_with_covariance(frame)
        np.testing.assert_allclose(mean, p.mean[t], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(cov, p.covariance[t], rtol=1e-12, atol=1e-18)


def test_python_fit_equals_the_commands_fit_and_its_file_is_read_by_the_command(folder, tmp_path):
    for method, extra in [("hmm", []), ("tsc-hmm", []), ("hmm:states=5", ["--standardise"])]:
        cli_file = tmp_path / "cli.json"
        run("fit", "--data", folder, "--method", method, *extra, "-o", cli_file)
        demos = datasets.load_demonstrations(folder)
        model = InteractionModel(method, standardise=bool(extra)).fit(demos, human=["p1_wrist_*"], robot=["p2_wrist_*"])
        ours = json.loads(model.to_json())
        theirs = json.loads(cli_file.read_text())
        assert ours["model"] == theirs["model"], method
        assert ours["layout"] == theirs["layout"] and ours["standardisation"] == theirs["standardisation"]
        assert ours["fit"]["log_likelihood"] == theirs["fit"]["log_likelihood"]
        py_file = tmp_path / "py.json"
        model.save(py_file)
        run("predict", "--model", py_file, "--data", folder / "test_00.csv", "-o", tmp_path / "p.csv")
        _, rows = read_csv(tmp_path / "p.csv")
        cli = np.array([[float(v) for v in r[1:]] for r in rows])
        np.testing.assert_array_equal(model.predict(datasets.read_demonstration(folder / "test_00.csv"), False).mean, cli)


def test_inputs_options_pickle_and_errors(folder):
    pd = pytest.importorskip("pandas")
    frames = datasets.load_demonstrations(folder, as_frame=True)
    arrays = [f.to_numpy() for f in frames]
    a = InteractionModel("hmm", states=3, reg=1e-3, seed=1).fit(frames, human=["p1_*"], robot=["p2_*"])
    b = InteractionModel("hmm", states=3, reg=1e-3, seed=1).fit(arrays, human=[0, 1, 2], robot=[3, 4, 5])
    assert a.n_states == b.n_states == 3
    test = datasets.read_demonstration(folder / "test_00.csv")
    np.testing.assert_array_equal(a.predict(test).mean, b.predict(test.values[:, :3]).mean)
    # the human's columns only, as a DataFrame or an array in the model's order
    np.testing.assert_array_equal(a.predict(pd.DataFrame(test.values[:, :3], columns=COLUMNS[:3])).mean, a.predict(test).mean)
    c = pickle.loads(pickle.dumps(a))
    np.testing.assert_array_equal(c.predict(test).mean, a.predict(test).mean)
    assert a.fit_summary["iterations"] >= 1
    with pytest.raises(ValueError, match="unknown option"):
        InteractionModel("hmm", colour=3).fit(frames)
    # Options whose default is not written in files are options all the same:
    # reg_units="relative" is the method key reg-rel, to the bit.
    r = InteractionModel("hmm", states=3, reg=5e-2, reg_units="relative", seed=1).fit(frames, human=["p1_*"], robot=["p2_*"])
    s = InteractionModel("hmm:reg-rel=5e-2", states=3, seed=1).fit(frames, human=["p1_*"], robot=["p2_*"])
    np.testing.assert_array_equal(r.predict(test).mean, s.predict(test).mean)
    assert not np.array_equal(r.predict(test).mean, InteractionModel("hmm", states=3, reg=5e-2, seed=1).fit(frames, human=["p1_*"], robot=["p2_*"]).predict(test).mean)
    # reg_units="positions" is the method key reg-pos, to the bit, and differs
    # from "relative" (the velocities are regularised by their positions' variances).
    q = InteractionModel("hmm", states=3, reg=5e-2, reg_units="positions", seed=1).fit(frames, human=["p1_*"], robot=["p2_*"])
    t = InteractionModel("hmm:reg-pos=5e-2", states=3, seed=1).fit(frames, human=["p1_*"], robot=["p2_*"])
    np.testing.assert_array_equal(q.predict(test).mean, t.predict(test).mean)
    assert not np.array_equal(q.predict(test).mean, r.predict(test).mean)
    with pytest.raises(ValueError, match="no column matches `nose_\\*`"):
        InteractionModel("hmm").fit(frames, human=["nose_*"], robot=["p2_*"])
    with pytest.raises(ValueError, match="needs the human's column `p1_wrist_x`"):
        a.predict(pd.DataFrame(test.values[:, 3:], columns=COLUMNS[3:]))
    with pytest.raises(ValueError, match="--method|method"):
        InteractionModel("no-such-method").fit(frames)
    online = a.online()
    with pytest.raises(ValueError, match="3 values"):
        online.step([1.0, 2.0])
    mean, cov = online.step_with_covariance(np.array([0.1, 0.0, 0.1]))
    assert mean.shape == (6,) and cov.shape == (6, 6)
