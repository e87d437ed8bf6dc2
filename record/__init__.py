"""The run record (``results.json``): what a bench run measured, judged and compared.

One :class:`RunRecord` per run holds the environment, one :class:`SuiteRecord` per suite with its
:class:`Trial` list (raw samples plus per-trial :class:`Measurement` s) and suite-level
measurements, the baseline comparison and the verdict. :class:`RecordWriter` keeps it on disk
as trials finish (a journal appended per trial, ``results.json`` rewritten per suite), so an
interrupted run loses nothing measured and can be resumed. The JSON schema (``armbench-run/1``)
is documented field by field in ``docs/record.md``; readers ignore keys they do not know, so
fields may be added without a new schema version.

Times: ``created``/``resumed`` are wall-clock ISO 8601 labels; every ``*_s`` field is seconds of
run time on the monotonic clock (see :meth:`RecordWriter.elapsed_s`).

Rooms: ``fields`` (vocabulary, errors, checked JSON access), ``measurement`` (measurements,
trials, suites), ``comparison``, ``environment`` (with ``dut``, the unit under test, and
``ci_run``, the CI job), ``run_record`` (the record, loading it),
``files`` (names, paths, atomic writes), ``jsonformat`` (the JSON text), ``journal`` (trials
appended between writes of ``results.json``, samples kept on disk), ``writer``. Beside them, what
the bench and the report share about a record: ``limits``, ``baseline``, ``fleet_index``,
``suite_contract`` (what every suite's contract shares, and the registry that finds each by
suite name; the contracts themselves live beside their suites) and ``interim`` (the figures of a
suite interrupted before its summary). A
layer below the bench, which writes records, and the report, which reads them
(``docs/architecture.md``).
"""

if __name__ != "armbench.record":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.record: import it by that name")

from armbench.record.comparison import Comparison, ComparisonRow
from armbench.record.environment import (
    Environment,
    capture_environment,
    git_revision,
    new_run_id,
    utc_timestamp,
)
from armbench.record.fields import (
    Better,
    Outcome,
    RecordError,
    RowStatus,
    SuiteStatus,
    TrialStatus,
    Verdict,
)
from armbench.record.files import (
    CAPTURE_FILE,
    JOURNAL_FILE,
    LEGACY_CAPTURE_FILE,
    REPORT_FILE,
    RESULTS_FILE,
    atomic_write_bytes,
    path_inside,
    run_directory,
)
from armbench.record.journal import StoredSamples
from armbench.record.jsonformat import json_default
from armbench.record.measurement import Measurement, SuiteRecord, Trial, default_better, judge
from armbench.record.run_record import (
    PAPER_REFERENCE,
    SCHEMA,
    TOO_DEEP,
    RunRecord,
    load_record,
    validate_record,
)
from armbench.record.writer import RecordWriter, continued_clock_s

__all__ = [
    "CAPTURE_FILE",
    "JOURNAL_FILE",
    "LEGACY_CAPTURE_FILE",
    "PAPER_REFERENCE",
    "REPORT_FILE",
    "RESULTS_FILE",
    "SCHEMA",
    "TOO_DEEP",
    "Better",
    "Comparison",
    "ComparisonRow",
    "Environment",
    "Measurement",
    "Outcome",
    "RecordError",
    "RecordWriter",
    "RowStatus",
    "RunRecord",
    "StoredSamples",
    "SuiteRecord",
    "SuiteStatus",
    "Trial",
    "TrialStatus",
    "Verdict",
    "atomic_write_bytes",
    "capture_environment",
    "continued_clock_s",
    "default_better",
    "git_revision",
    "json_default",
    "judge",
    "load_record",
    "new_run_id",
    "path_inside",
    "run_directory",
    "utc_timestamp",
    "validate_record",
]
