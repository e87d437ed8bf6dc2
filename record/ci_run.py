"""The CI job a run was part of (:class:`CiRun`), read from the variables GitHub Actions and
GitLab CI set, so a record leads back to the pipeline, the commit and the job that made it.

Only what the CI system sets is taken: GitHub Actions when ``GITHUB_ACTIONS=true``
(``GITHUB_REPOSITORY``, ``GITHUB_SHA``, ``GITHUB_REF_NAME``, ``GITHUB_WORKFLOW``,
``GITHUB_RUN_ID``, ``GITHUB_RUN_ATTEMPT``, and the run's address from ``GITHUB_SERVER_URL``),
GitLab CI when ``GITLAB_CI=true`` (``CI_PROJECT_PATH``, ``CI_COMMIT_SHA``,
``CI_COMMIT_REF_NAME``, ``CI_PIPELINE_ID``, ``CI_JOB_ID``, ``CI_JOB_URL``, ``CI_PIPELINE_URL``).
A value that is not printable text of at most :data:`MAX_CI_TEXT` characters is left out: the
run is not refused for its CI's environment.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

from armbench.drivers.model.settings import SettingsError
from armbench.record.dut import printable_text
from armbench.record.fields import _obj, _opt_str, _str

__all__ = ["MAX_CI_TEXT", "CiRun", "ci_run"]

#: The longest CI value (characters) kept: addresses are longer than names.
MAX_CI_TEXT = 500


@dataclass(frozen=True, slots=True)
class CiRun:
    """One CI job: the ``system`` (``"github-actions"``, ``"gitlab-ci"``), the ``project``, the
    ``commit`` and ``ref`` it built, its ``workflow``, ``pipeline_id``, ``attempt`` and
    ``job_id``, and the addresses of the job (``url``) and of its pipeline (``pipeline_url``);
    None where the system did not say."""

    system: str
    project: str | None = None
    commit: str | None = None
    ref: str | None = None
    workflow: str | None = None
    pipeline_id: str | None = None
    attempt: str | None = None
    job_id: str | None = None
    url: str | None = None
    pipeline_url: str | None = None

    def items(self) -> list[tuple[str, str]]:
        """The known values as ``(key, value)``, in field order."""
        return [(f.name, v) for f in fields(self) if (v := getattr(self, f.name)) is not None]

    def to_json(self) -> dict[str, str | None]:
        """The JSON object of this job (``environment.ci``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json(cls, data: object, where: str) -> CiRun:
        """Parse ``environment.ci``; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        values = {f.name: _opt_str(d.get(f.name), f"{where}.{f.name}") for f in fields(cls)
                  if f.name != "system"}
        return cls(system=_str(d.get("system"), f"{where}.system"), **values)


def _text(environ: Mapping[str, str], name: str) -> str | None:
    value = environ.get(name)
    if value is None:
        return None
    try:
        return printable_text(name, value, MAX_CI_TEXT)
    except SettingsError:
        return None


def ci_run(environ: Mapping[str, str]) -> CiRun | None:
    """The CI job ``environ`` (the process's environment) describes, None outside CI."""
    if environ.get("GITHUB_ACTIONS") == "true":
        project, run_id = _text(environ, "GITHUB_REPOSITORY"), _text(environ, "GITHUB_RUN_ID")
        server, attempt = _text(environ, "GITHUB_SERVER_URL"), _text(environ, "GITHUB_RUN_ATTEMPT")
        url = None
        if server and project and run_id:
            url = f"{server.rstrip('/')}/{project}/actions/runs/{run_id}"
            if attempt:
                url += f"/attempts/{attempt}"
        return CiRun("github-actions", project=project, commit=_text(environ, "GITHUB_SHA"),
                     ref=_text(environ, "GITHUB_REF_NAME"),
                     workflow=_text(environ, "GITHUB_WORKFLOW"), pipeline_id=run_id,
                     attempt=attempt, url=url)
    if environ.get("GITLAB_CI") == "true":
        return CiRun("gitlab-ci", project=_text(environ, "CI_PROJECT_PATH"),
                     commit=_text(environ, "CI_COMMIT_SHA"),
                     ref=_text(environ, "CI_COMMIT_REF_NAME"),
                     pipeline_id=_text(environ, "CI_PIPELINE_ID"),
                     job_id=_text(environ, "CI_JOB_ID"), url=_text(environ, "CI_JOB_URL"),
                     pipeline_url=_text(environ, "CI_PIPELINE_URL"))
    return None
