"""The CI recipes of ``docs/ci.md`` run as written, end to end: each job's steps in order, as
``act`` (GitHub Actions) or a runner (GitLab CI) would run them.

What is real: every ``run:`` and ``script:`` line, run by ``bash -e`` with the job's variables;
``pip install "$ARMBENCH"`` of this checkout's wheel into a fresh virtual environment (the
workflow's placeholder address replaced by the wheel, as a lab points it at its own copy; the
dependencies come from the environment the venv sees, as on a runner with a warm cache);
``armbench`` from that install; the ``if:`` and ``rules:`` conditions, evaluated for a push to
the default branch and for a pull or merge request; GitLab's ``curl`` and ``unzip``.

What the test stands in for, as it cannot be real here: the runner's container image (a venv
on this machine); the four GitHub actions the workflow uses (checkout copies the lab's files
into a workspace that stays between runs, the harder case for a rerun; setup-python makes the
venv; upload and download of artifacts keep folders between the runs); GitLab's job artifacts
API, served to the recipe's own ``curl`` over HTTP by the test. An action or a key the test
does not know fails it: the recipe cannot grow a step no test runs.
"""

from __future__ import annotations

import http.server
import io
import os
import re
import shutil
import subprocess
import sys
import threading
import venv
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import pytest
import yaml  # type: ignore[import-untyped]
from conftest import shared_wheel
from netutil import free_port

from armbench.drivers.model.settings import read_toml
from armbench.record import load_record
from armbench.record.verdict import EXIT_FAIL, EXIT_PASS, EXIT_REGRESSION

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "ci.md"
#: A step's outcome: its exit status, or None when its condition skipped it.
Outcome = int | None


def _doc() -> str:
    return DOC.read_text(encoding="utf-8")


def _block(after: str, language: str, containing: str = "") -> str:
    """The first ``language`` code block after the text ``after`` (holding ``containing``)."""
    text = _doc()
    for found in re.finditer(rf"```{language}\n(.*?)```", text[text.index(after):], re.S):
        if containing in found.group(1):
            return found.group(1)
    raise AssertionError(f"no {language} block after {after!r} holding {containing!r}")


def _bench_toml() -> str:
    return _block("**The config file.**", "toml")


# -- the runner's machine ----------------------------------------------------------------------


@dataclass
class Machine:
    """Where the jobs run: the lab's repository, a venv per job, the artifacts kept between
    runs, and the wheel ``$ARMBENCH`` names."""

    root: Path
    wheel: Path
    repo: Path
    store: dict[str, Path] = field(default_factory=dict)
    venvs: int = 0
    log: list[str] = field(default_factory=list)

    def fresh_python(self) -> Path:
        """setup-python (GitHub) or the image's Python (GitLab): a new venv's ``bin``."""
        self.venvs += 1
        home = self.root / f"venv-{self.venvs}"
        venv.EnvBuilder(with_pip=True, system_site_packages=True).create(home)
        return home / "bin"

    def checkout(self, workspace: Path) -> None:
        """The lab's files into the workspace (what the job had before stays: a rerun)."""
        shutil.copytree(self.repo, workspace, dirs_exist_ok=True)

    def shell(self, command: str, cwd: Path, env: Mapping[str, str]) -> int:
        done = subprocess.run(["bash", "-e", "-c", command], cwd=cwd, env=dict(env),
                              capture_output=True, text=True, timeout=600, check=False)
        self.log.append(f"$ {command}\n{done.stdout}{done.stderr}(exit {done.returncode})")
        return done.returncode


def _base_env(bin_dir: Path | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("VIRTUAL_ENV", "PYTHONPATH") and not k.startswith(("GITHUB_", "CI_"))}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    if bin_dir is not None:
        env["PATH"] = f"{bin_dir}{os.pathsep}{env['PATH']}"
    return env


@pytest.fixture(scope="module")
def machine(tmp_path_factory: pytest.TempPathFactory) -> Machine:
    root = tmp_path_factory.mktemp("ci")
    repo = root / "lab-repo"
    repo.mkdir()
    (repo / "bench.toml").write_text(_bench_toml(), encoding="utf-8")
    wheel = shared_wheel(tmp_path_factory, "pure-wheel", pure=True)
    return Machine(root, wheel, repo)


# -- GitHub Actions ------------------------------------------------------------------------------


def _github_if(expression: str | None, event: str, ref: str, failed: bool) -> bool:
    """A step's ``if:`` for this subset of GitHub's expressions: ``github.ref``,
    ``github.event_name``, ``==``, ``&&``, ``||``, ``always()``, ``success()``, ``failure()``;
    without a status function a step runs only after steps that succeeded."""
    if expression is None:
        return not failed
    text = (expression.replace("github.event_name", repr(event)).replace("github.ref", repr(ref))
            .replace("always()", "True").replace("success()", repr(not failed))
            .replace("failure()", repr(failed)).replace("&&", " and ").replace("||", " or "))
    assert re.fullmatch(r"[\w\s'/.=()-]*", text), f"an expression the test does not know: {text}"
    value = bool(eval(text, {"__builtins__": {}}))  # our own docs: literals, ==, and, or
    uses_status = any(f in expression for f in ("always()", "success()", "failure()"))
    return value if uses_status else value and not failed


def _action(machine: Machine, step: Mapping[str, Any], workspace: Path,
            env: dict[str, str]) -> int:
    """One ``uses:`` step, done as the action does it (see the module docstring)."""
    name = str(step["uses"]).split("@")[0]
    given: Mapping[str, Any] = step.get("with", {})
    if name == "actions/checkout":
        machine.checkout(workspace)
    elif name == "actions/setup-python":
        assert str(given.get("python-version", "")).startswith("3.")
        bin_dir = machine.fresh_python()
        env["PATH"] = f"{bin_dir}{os.pathsep}{env['PATH']}"
    elif name == "actions/upload-artifact":
        source = workspace / str(given["path"])
        if not source.exists():
            return 1
        kept = machine.root / "artifacts" / str(given["name"])
        shutil.rmtree(kept, ignore_errors=True)
        shutil.copytree(source, kept)
        machine.store[str(given["name"])] = kept
    elif name == "dawidd6/action-download-artifact":
        assert given.get("branch") == "main"
        stored = machine.store.get(str(given["name"]))
        if stored is None:
            return 1
        shutil.copytree(stored, workspace / str(given["path"]), dirs_exist_ok=True)
    else:
        raise AssertionError(f"an action the test does not run: {name}")
    return 0


def _github(machine: Machine, workspace: Path, *, event: str, ref: str,
            env_over: Mapping[str, str] = {}) -> dict[str, Outcome]:
    """The workflow's one job for ``event`` on ``ref`` in ``workspace``: each step's outcome."""
    workflow: dict[str, Any] = yaml.safe_load(_block("## GitHub Actions", "yaml"))
    (job,) = workflow["jobs"].values()
    workspace.mkdir(exist_ok=True)
    env = _base_env(None)
    env.update({k: str(v) for k, v in {**workflow.get("env", {}), **job.get("env", {})}.items()})
    env.update({"GITHUB_ACTIONS": "true", "GITHUB_EVENT_NAME": event, "GITHUB_REF": ref,
                "GITHUB_WORKSPACE": str(workspace), "ARMBENCH": str(machine.wheel),
                "GITHUB_STEP_SUMMARY": str(workspace / "step-summary.md"), **env_over})
    outcomes: dict[str, Outcome] = {}
    failed = False
    for k, step in enumerate(job["steps"]):
        assert set(step) <= {"name", "if", "uses", "with", "run"}, step
        label = str(step.get("name") or step.get("uses") or step["run"])
        if not _github_if(step.get("if"), event, ref, failed):
            outcomes[label] = None
            continue
        status = (_action(machine, step, workspace, env) if "uses" in step
                  else machine.shell(str(step["run"]), workspace, env))
        outcomes[label if label not in outcomes else f"{label} ({k})"] = status
        failed = failed or status != 0
    return outcomes


@pytest.mark.slow  # a wheel build and five jobs, each installing it (~2 min)
def test_the_github_workflow_runs_as_written(machine: Machine) -> None:
    main = _github(machine, machine.root / "gh-main", event="push", ref="refs/heads/main")
    assert main == {"actions/checkout@v4": 0, "actions/setup-python@v5": 0,
                    'pip install "$ARMBENCH"': 0, "baseline (main)": 0,
                    "fetch the baseline of main": None, "judge against the baseline": None,
                    "keep the baseline": 0, "keep the report": None}, machine.log
    baseline = load_record(machine.store["armbench-baseline"] / "results.json")
    assert baseline.environment.ci is not None
    assert baseline.environment.ci.system == "github-actions"
    assert baseline.environment.dut is not None and baseline.environment.dut.name == "arm-3"

    pr = machine.root / "gh-pr"
    for _ in range(2):  # a rerun in the same workspace: --overwrite
        done = _github(machine, pr, event="pull_request", ref="refs/pull/7/merge")
        assert done["judge against the baseline"] == EXIT_PASS, machine.log[-1]
        assert done["baseline (main)"] is None and done["keep the report"] == 0
    summary = (pr / "step-summary.md").read_text(encoding="utf-8")
    assert summary.count("PASS (exit 0)") == 2 and "0 regressed" in summary
    assert (machine.store["armbench-report"] / "junit.xml").is_file()

    heavy = _github(machine, machine.root / "gh-heavy", event="pull_request",
                    ref="refs/pull/8/merge", env_over={"ARM_PORT": "fake://?payload=2.5"})
    assert heavy["judge against the baseline"] == EXIT_REGRESSION, machine.log[-2]
    assert heavy["keep the report"] == 0  # always(): the report of a failed job is kept
    assert "REGRESSION (exit 3)" in (machine.root / "gh-heavy" / "step-summary.md").read_text(
        encoding="utf-8")

    lab, branch = machine.repo, machine.root / "tight-branch"  # a pull request tightening it
    shutil.copytree(lab, branch)
    bench = branch / "bench.toml"
    bench.write_text(bench.read_text(encoding="utf-8").replace("high = 2.0", "high = 0.000001",
                                                               1), encoding="utf-8")
    machine.repo = branch
    try:
        done = _github(machine, machine.root / "gh-tight", event="pull_request",
                       ref="refs/pull/9/merge")
    finally:
        machine.repo = lab
    assert done["judge against the baseline"] == EXIT_FAIL, machine.log[-2]
    assert "accuracy.coordinated.mean_mm" in (machine.root / "gh-tight" / "step-summary.md"
                                              ).read_text(encoding="utf-8")


# -- GitLab CI -----------------------------------------------------------------------------------


class _Artifacts:
    """GitLab's job artifacts API for this test: the newest archive of each job on each ref,
    behind the job token."""

    def __init__(self, token: str) -> None:
        self.token = token
        self.archives: dict[tuple[str, str], bytes] = {}
        self.requests: list[str] = []

    def keep(self, job: str, ref: str, workspace: Path, paths: list[str]) -> None:
        data = io.BytesIO()
        with zipfile.ZipFile(data, "w") as archive:
            for name in paths:
                path = workspace / name
                files = ([path] if not path.is_dir()
                         else sorted(p for p in path.rglob("*") if p.is_file()))
                for file in files:
                    archive.write(file, file.relative_to(workspace).as_posix())
        self.archives[(job, ref)] = data.getvalue()


def _serve(api: _Artifacts) -> tuple[http.server.ThreadingHTTPServer, str]:
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            url = urlsplit(self.path)
            api.requests.append(self.path)
            found = re.fullmatch(r"/api/v4/projects/(\d+)/jobs/artifacts/([^/]+)/download",
                                 url.path)
            job = parse_qs(url.query).get("job", [""])[0]
            body = api.archives.get((job, found.group(2))) if found else None
            if self.headers.get("JOB-TOKEN") != api.token:
                self.send_response(401)
                body = None
            elif body is None:
                self.send_response(404)
            else:
                self.send_response(200)
                self.send_header("Content-Type", "application/zip")
            self.send_header("Content-Length", str(len(body or b"")))
            self.end_headers()
            self.wfile.write(body or b"")

        def log_message(self, *args: Any) -> None:
            pass

    port = free_port()
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, f"http://127.0.0.1:{port}/api/v4"


def _gitlab_rule(rule: str, variables: Mapping[str, str]) -> bool:
    """A ``rules: - if:`` of this subset: ``$VAR``, quoted strings, ``==``, ``&&``, ``||``."""
    text = re.sub(r"\$(\w+)", lambda m: repr(variables.get(m.group(1))), rule)
    text = text.replace("&&", " and ").replace("||", " or ")
    assert re.fullmatch(r"[\w\s'\"=_-]*", text), f"a rule the test does not know: {text}"
    return bool(eval(text, {"__builtins__": {}}))  # our own docs: literals, ==, and, or


def _gitlab(machine: Machine, api: _Artifacts, workspace: Path,
            pipeline: Mapping[str, str]) -> dict[str, Outcome]:
    """Every job of the pipeline ``pipeline`` (its predefined variables) adds: its script's
    status (None: its rules left it out); a passed job's artifacts are kept."""
    config: dict[str, Any] = yaml.safe_load(_block("## GitLab CI", "yaml"))
    outcomes: dict[str, Outcome] = {}
    for name, job in config.items():
        if name == "variables":
            continue
        assert set(job) <= {"image", "rules", "script", "artifacts"}, job
        variables = {**{k: str(v) for k, v in config.get("variables", {}).items()}, **pipeline,
                     "ARMBENCH": str(machine.wheel), "GITLAB_CI": "true",
                     "CI_JOB_TOKEN": api.token}
        if not any(_gitlab_rule(rule["if"], variables) for rule in job["rules"]):
            outcomes[name] = None
            continue
        assert str(job["image"]).startswith("python:3")
        workspace.mkdir(exist_ok=True)
        machine.checkout(workspace)
        env = {**_base_env(machine.fresh_python()), **variables}
        status = 0
        for line in job["script"]:
            status = machine.shell(str(line), workspace, env)
            if status != 0:
                break
        outcomes[name] = status
        artifacts = job.get("artifacts", {})
        if status == 0 or artifacts.get("when") == "always":
            api.keep(name, pipeline.get("CI_COMMIT_REF_NAME", ""), workspace, artifacts["paths"])
    return outcomes


@pytest.mark.slow  # a wheel build and three jobs, each installing it (~1 min)
def test_the_gitlab_pipeline_runs_as_written(machine: Machine) -> None:
    api = _Artifacts(token="job-token-42")
    server, url = _serve(api)
    try:
        common = {"CI_DEFAULT_BRANCH": "main", "CI_API_V4_URL": url, "CI_PROJECT_ID": "17"}
        main = _gitlab(machine, api, machine.root / "gl-main",
                       {**common, "CI_PIPELINE_SOURCE": "push", "CI_COMMIT_BRANCH": "main",
                        "CI_COMMIT_REF_NAME": "main"})
        assert main == {"baseline": 0, "judge": None}, machine.log
        merge = machine.root / "gl-merge"
        for _ in range(2):  # a rerun in the same folder: unzip -o, --overwrite
            done = _gitlab(machine, api, merge,
                           {**common, "CI_PIPELINE_SOURCE": "merge_request_event",
                            "CI_COMMIT_REF_NAME": "feature"})
            assert done == {"baseline": None, "judge": EXIT_PASS}, machine.log[-1]
    finally:
        server.shutdown()
    assert api.requests and all("job=baseline" in r for r in api.requests)
    assert (merge / "current" / "junit.xml").is_file()
    record = load_record(merge / "current" / "results.json")
    assert record.baseline is not None and record.environment.ci is not None
    assert record.environment.ci.system == "gitlab-ci"


# -- the config file -----------------------------------------------------------------------------


def test_the_bench_toml_shown_is_cut_from_config_show(tmp_path: Path) -> None:
    """``armbench config show accuracy > bench.toml`` as the page says; the file the page shows
    keeps a subset of its tables and keys (the jobs above run with it)."""
    command = _block("**The config file.**", "sh", "config show").strip()
    shim = tmp_path / "bin"
    shim.mkdir()
    (shim / "armbench").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m armbench "$@"\n')
    (shim / "armbench").chmod(0o755)
    done = subprocess.run(["bash", "-e", "-c", command], cwd=tmp_path, env=_base_env(shim),
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    full = read_toml(tmp_path / "bench.toml", "bench.toml")
    (tmp_path / "shown.toml").write_text(_bench_toml(), encoding="utf-8")
    shown = read_toml(tmp_path / "shown.toml", "shown.toml")
    for table in ("limits", "suites"):
        for key, value in shown[table].items():
            assert key in full[table], key
            assert set(value) <= set(full[table][key]), key
    assert shown["spec_version"] == full["spec_version"]
