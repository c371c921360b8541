"""`python -m pipelines.materialize` (what `make demo` runs): one line per finished step off a terminal, the
failing step named, a text log per run, every group known, and a one-line error for an unknown group."""

import json
import os

import dagster as dg
import pytest

from pipelines import materialize
from pipelines.instance import TEMPLATE, InstanceError, dagster_home
from pipelines.progress import progress_logger


@dg.asset
def upstream() -> int:
    return 2


@dg.asset
def downstream(context: dg.AssetExecutionContext, upstream: int) -> int:
    context.log.info(f"squaring {upstream}")
    return upstream**2


@dg.asset
def broken(upstream: int) -> int:
    raise RuntimeError("this asset always fails")


@dg.asset_check(asset=upstream)
def upstream_is_odd() -> dg.AssetCheckResult:
    return dg.AssetCheckResult(passed=False, severity=dg.AssetCheckSeverity.WARN, metadata={"smallest": 2})


@dg.asset_check(asset=upstream)
def upstream_is_small() -> dg.AssetCheckResult:
    return dg.AssetCheckResult(passed=False, severity=dg.AssetCheckSeverity.WARN, metadata={"where": "x" * 400 + "END"})


@dg.asset_check(asset=upstream)
def upstream_is_positive() -> dg.AssetCheckResult:
    return dg.AssetCheckResult(passed=True)


def _job(*assets, checks=()) -> dg.JobDefinition:
    return dg.Definitions(assets=list(assets), asset_checks=list(checks), loggers={"progress": progress_logger}).resolve_implicit_global_asset_job_def()


def test_success_prints_a_line_per_step_and_writes_the_log(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    ok, line = materialize.run(_job(upstream, downstream), "toy", dg.DagsterInstance.ephemeral())
    err = capsys.readouterr().err
    assert ok and line.startswith("toy: 2 steps in ")
    assert "[toy 1/2] upstream done in" in err and "[toy 2/2] downstream done in" in err
    (log,) = (tmp_path / "logs").glob("*_toy.log")
    text = log.read_text()
    assert "STEP_SUCCESS" in text and "squaring 2" in text  # user messages and Dagster events, one file


def test_failure_names_the_step_and_shows_the_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    ok, line = materialize.run(_job(upstream, broken), "toy", dg.DagsterInstance.ephemeral())
    err = capsys.readouterr().err
    assert not ok and line.startswith("toy: FAILED at broken after ")
    assert "broken FAILED in" in err and "this asset always fails" in err
    # the error once: not again in Dagster's "Execution of run ... failed. Steps failed: [...]" (the caller's line says it)
    assert [ln for ln in err.splitlines() if ln.startswith("ERROR")] == [next(ln for ln in err.splitlines() if "this asset always fails" in ln)]


def test_a_failed_check_is_printed_though_its_step_succeeds(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    ok, _ = materialize.run(_job(upstream, checks=[upstream_is_odd, upstream_is_positive]), "toy", dg.DagsterInstance.ephemeral())
    err = capsys.readouterr().err
    assert ok
    assert "WARN upstream_upstream_is_odd: check upstream_is_odd on upstream did not pass: smallest=2" in err
    assert "upstream_is_positive on upstream did not pass" not in err
    (log,) = (tmp_path / "logs").glob("*_toy.log")
    assert "ASSET_CHECK_EVALUATION Asset check 'upstream_is_odd' on 'upstream' did not pass. smallest=2" in log.read_text()  # what it measured too


def test_a_long_check_record_is_cut_visibly_and_kept_whole_in_the_log(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    materialize.run(_job(upstream, checks=[upstream_is_small]), "toy", dg.DagsterInstance.ephemeral())
    (line,) = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("WARN")]
    (log,) = (tmp_path / "logs").glob("*_toy.log")
    assert "END" not in line and line.endswith(f"xxx… (whole in {log})")
    assert "x" * 400 + "END" in log.read_text()


def test_every_asset_group_has_a_job():
    assert set(materialize.group_jobs()) == {"aviation", "trajectory", "urban", "dcb"}


def test_unknown_group_is_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        materialize.main(["aviation", "nonsense"])
    assert exc.value.code == 2
    assert "unknown group nonsense; the groups are aviation, trajectory, urban, dcb" in capsys.readouterr().err


def test_config_json_configures_steps_and_a_failure_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    monkeypatch.setenv("DAGSTER_HOME", str(tmp_path))
    bad_path = {"ops": {"flight_ingest": {"config": {"source_path": str(tmp_path / "none.csv")}}}}
    assert materialize.main(["aviation", "--config-json", json.dumps(bad_path)]) == 1
    out, err = capsys.readouterr()
    assert "none.csv: no such file" in err and "aviation: FAILED at flight_ingest" in out
    assert "Not executing" not in err  # the steps skipped after the failure are not each an error line
    for config, message in [
        ({"ops": {"flight_ingest": {"config": {"source_pth": "x.csv"}}}}, "--config-json for aviation: Received unexpected config entry \"source_pth\""),
        ({"ops": {"trajectory_models": {}}}, "names steps trajectory_models that the groups aviation, dcb do not run"),
        ({"flight_ingest": {"config": {"source_path": "x.csv"}}}, 'expected {"ops": {STEP: {"config": {...}}}}'),  # "ops" forgotten
        ({"ops": []}, 'expected {"ops": {STEP: {"config": {...}}}}'),
        ({"ops": {"dcb_delays": {"config": {"episodes": "many"}}}}, "--config-json for dcb: "),  # the second group's
    ]:
        with pytest.raises(SystemExit) as exc:  # before any run: a second group's bad config is not found minutes in
            materialize.main(["aviation", "dcb", "--config-json", json.dumps(config)])
        last = capsys.readouterr().err.strip().splitlines()[-1]  # after argparse's usage: the error, on one line
        assert exc.value.code == 2 and last.startswith("python -m pipelines.materialize: error: ") and message in last


def test_runs_without_dagster_home_in_the_instance_under_trafficlearn_home(tmp_path, monkeypatch, capsys):
    """As the README's "Bring your own data" command is typed, outside make: no DAGSTER_HOME set. The run goes to
    $TRAFFICLEARN_HOME/dagster with the checkout's dagster.yaml (Dagster alone stops with a page about DAGSTER_HOME)."""
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    monkeypatch.setenv("DAGSTER_HOME", "")  # recorded, so that the value the run exports is undone after the test
    monkeypatch.delenv("DAGSTER_HOME")
    bad_path = {"ops": {"flight_ingest": {"config": {"source_path": str(tmp_path / "none.csv")}}}}
    assert materialize.main(["aviation", "--config-json", json.dumps(bad_path)]) == 1
    out, err = capsys.readouterr()
    assert "none.csv: no such file" in err and "aviation: FAILED at flight_ingest" in out
    assert (tmp_path / "dagster" / "dagster.yaml").read_text() == TEMPLATE.read_text()
    with dg.DagsterInstance.get() as instance:  # DAGSTER_HOME now points there: the failed run is recorded in it
        assert instance.root_directory == str(tmp_path / "dagster") and len(instance.get_runs()) == 1


def test_a_set_dagster_home_is_used_as_it_is(tmp_path, monkeypatch):
    monkeypatch.setenv("DAGSTER_HOME", str(tmp_path / "mine"))
    assert dagster_home() == tmp_path / "mine" and not (tmp_path / "mine" / "dagster.yaml").exists()


def test_a_relative_dagster_home_is_exported_absolute_and_an_own_dagster_yaml_is_kept(tmp_path, monkeypatch):
    # absolute, so that `python -m pipelines.dev`, which runs Dagster from that folder, still means the same one
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DAGSTER_HOME", "rel")
    assert dagster_home() == tmp_path / "rel" and os.environ["DAGSTER_HOME"] == str(tmp_path / "rel")
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("DAGSTER_HOME")
    (tmp_path / "home" / "dagster").mkdir(parents=True)
    (tmp_path / "home" / "dagster" / "dagster.yaml").write_text("telemetry:\n  enabled: false\n")
    assert dagster_home() == tmp_path / "home" / "dagster"
    assert (tmp_path / "home" / "dagster" / "dagster.yaml").read_text() == "telemetry:\n  enabled: false\n"


def test_an_instance_dagster_yaml_older_than_the_checkouts_is_replaced_as_make_does(tmp_path, monkeypatch):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path))
    monkeypatch.setenv("DAGSTER_HOME", "")
    monkeypatch.delenv("DAGSTER_HOME")
    stale = tmp_path / "dagster" / "dagster.yaml"
    stale.parent.mkdir()
    stale.write_text("telemetry:\n  enabled: true\n")
    old = TEMPLATE.stat().st_mtime - 60
    os.utime(stale, (old, old))
    dagster_home()
    assert stale.read_text() == TEMPLATE.read_text()


def test_a_file_where_the_instance_goes_is_one_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("DAGSTER_HOME", str(tmp_path / "file"))
    with pytest.raises(InstanceError, match=r"^DAGSTER_HOME .*file: not a usable folder \(File exists\)$"):
        dagster_home()
    monkeypatch.delenv("DAGSTER_HOME")
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(tmp_path / "file"))
    with pytest.raises(SystemExit) as exc:
        materialize.main(["aviation"])
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert exc.value.code == 2 and last.startswith("python -m pipelines.materialize: error: the Dagster instance") and "not a usable folder" in last


def test_a_misspelt_profile_is_one_line_before_any_run(tmp_path):
    # `make demo PROFILE=papr`: the configs' profile default was read while importing the assets, a traceback
    import subprocess
    import sys

    env = {**os.environ, "TRAFFICLEARN_HOME": str(tmp_path), "TRAFFICLEARN_PROFILE": "papr"}
    run = subprocess.run([sys.executable, "-m", "pipelines.materialize", "aviation"], env=env, capture_output=True, text=True,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines()[-1] == "python -m pipelines.materialize: error: TRAFFICLEARN_PROFILE='papr': expected one of demo, paper"
    assert not (tmp_path / "warehouse").exists()  # nothing ran
