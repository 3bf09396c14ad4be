"""The whole of a ``results.json``: :class:`Results` (an evaluation, or a batch evaluation with its units)
and :class:`DensifyBatchResults` (a batch densify), with :func:`read_results` to read one back.

JSON is only met here and in the records' ``to_json`` / ``from_json``: the rest of the code reads
attributes."""

from __future__ import annotations

import gzip
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sparself.core.errors import InputError
from sparself.evaluation.scene_results import SceneFailure, SceneResult, scene_from_json


def jsonable(x):
    """x with numpy numbers and arrays, tuples and paths made plain JSON values (and keys strings)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    return x


@dataclass
class Settings:
    """An evaluation's settings as results.json records them: every option of its ``EvalConfig`` (which
    options there are depends on the version of sparself that wrote the file, so they are kept as
    recorded, in order, and shown as a table), the package versions and the LPIPS status. The options the
    report explains are read through the properties, with the defaults of files that lack them."""

    recorded: dict[str, object] = field(default_factory=dict)

    def option(self, name: str, default=None):
        return self.recorded.get(name, default)

    @property
    def holdout_every(self) -> int:
        return int(self.option("holdout_every", 8))

    @property
    def sparse_holdout_every(self) -> int:
        return int(self.option("sparse_holdout_every", 2))

    @property
    def inputs(self) -> int | list[int]:
        """N: one number (results from before the sweep) or a list of them."""
        n = self.option("inputs", 25)
        return list(n) if isinstance(n, (list, tuple)) else int(n)

    @property
    def n_mid(self) -> int:
        return int(self.option("n_mid", 8))

    @property
    def n_extra(self) -> int:
        return int(self.option("n_extra", 2))

    @property
    def seeds(self) -> int:
        return int(self.option("seeds", 3))

    @property
    def points(self) -> str:
        return str(self.option("points", "capture"))  # results from before the option used the capture's

    @property
    def versions(self) -> dict[str, str]:
        v = self.option("versions", {})
        return dict(v) if isinstance(v, dict) else {}

    @property
    def lpips_status(self) -> str | None:
        s = self.option("lpips_status")
        return None if s is None else str(s)

    def for_batch(self, seeds: int, manifest: str) -> Settings:
        """The settings of a batch evaluation's combined report: its units' settings with the number of
        seeds over all units and the manifest (each unit ran one seed, its ``first_seed``)."""
        recorded = {**self.recorded, "seeds": seeds, "batch_manifest": manifest}
        recorded.pop("first_seed", None)
        return Settings(recorded)

    def table(self) -> list[tuple[str, object]]:
        """(name, value) of every recorded setting but the versions (a table of their own)."""
        return [(k, v) for k, v in self.recorded.items() if k != "versions"]


@dataclass
class UnitFailure:
    """A batch unit (a capture, and for evaluate a seed) that failed, with its one-line error."""

    capture: str
    seed: int
    error: str | None

    def to_json(self) -> dict:
        return {"capture": self.capture, "seed": self.seed, "error": self.error}

    @classmethod
    def from_json(cls, d: dict) -> UnitFailure:
        return cls(d["capture"], d["seed"], d.get("error"))


@dataclass
class UnitRecord:
    """What became of a batch unit, as its report shows it: status ("ok" or "failed", with a one-line
    error), seconds, densify's counts of real and synthesized views, whether an earlier run did it, and its
    output folder relative to the batch folder; a batch densify's rows also carry the capture's name
    and source."""

    capture: str
    seed: int
    status: str
    error: str | None = None
    seconds: float = 0.0
    views: int | None = None
    synthesized: int | None = None
    skipped: bool = False
    name: str | None = None
    source: str | None = None
    output: str | None = None

    def to_json(self) -> dict:
        d: dict = {"capture": self.capture, "seed": self.seed, "status": self.status, "error": self.error}
        d.update(seconds=self.seconds, views=self.views, synthesized=self.synthesized, skipped=self.skipped)
        if self.name is not None:
            d.update(name=self.name, source=self.source)
        if self.output is not None:
            d["output"] = self.output
        return d

    @classmethod
    def from_json(cls, d: dict) -> UnitRecord:
        return cls(
            d["capture"],
            d["seed"],
            d["status"],
            d.get("error"),
            d.get("seconds", 0.0),
            d.get("views"),
            d.get("synthesized"),
            bool(d.get("skipped", False)),
            d.get("name"),
            d.get("source"),
            d.get("output"),
        )


@dataclass
class Results:
    """An evaluation's results: settings, what was not run and why (by name), one record per run (capture
    x N); a batch evaluation adds its failed units and every unit's record."""

    settings: Settings = field(default_factory=Settings)
    not_run: dict[str, str] = field(default_factory=dict)
    scenes: list[SceneResult | SceneFailure] = field(default_factory=list)
    failures: list[UnitFailure] | None = None
    units: list[UnitRecord] | None = None  # a batch's units ("batch" in results.json)

    @property
    def ok(self) -> list[SceneResult]:
        return [s for s in self.scenes if isinstance(s, SceneResult) and s.status == "ok"]

    @property
    def failed(self) -> list[SceneResult | SceneFailure]:
        """The runs that did not finish: failed, or still running in a partial file."""
        return [s for s in self.scenes if s.status != "ok"]

    def to_json(self) -> dict:
        d: dict = {"settings": self.settings.recorded, "not_run": dict(self.not_run)}
        d["scenes"] = [s.to_json() for s in self.scenes]
        if self.failures is not None:
            d["failures"] = [f.to_json() for f in self.failures]
        if self.units is not None:
            d["batch"] = {"units": [u.to_json() for u in self.units]}
        return jsonable(d)

    @classmethod
    def from_json(cls, d: dict) -> Results:
        """Results read back from their JSON; ValueError, KeyError or TypeError when it is not results."""
        if not isinstance(d, dict) or not isinstance(d.get("scenes"), list):
            raise ValueError('expected a JSON object with a "scenes" list')
        if d.get("settings", {}).get("kind") == "densify":
            raise ValueError("the results of a batch densify, not of an evaluation")
        failures, batch = d.get("failures"), d.get("batch")
        return cls(
            Settings(dict(d.get("settings", {}))),
            dict(d.get("not_run", {})),
            [scene_from_json(s) for s in d["scenes"]],
            None if failures is None else [UnitFailure.from_json(f) for f in failures],
            None if batch is None else [UnitRecord.from_json(u) for u in batch.get("units", [])],
        )


@dataclass
class DensifyBatchResults:
    """A batch densify's results: the manifest, package versions, each capture's config as JSON (by capture
    name), one record per capture and the captures that failed."""

    manifest: str
    versions: dict[str, str]
    config: dict[str, object]
    units: list[UnitRecord]
    failures: list[UnitFailure]

    @property
    def ok(self) -> list[UnitRecord]:
        return [u for u in self.units if u.status == "ok"]

    def to_json(self) -> dict:
        return {
            "settings": {
                "kind": "densify",
                "manifest": self.manifest,
                "versions": self.versions,
                "config": self.config,
            },
            "scenes": [u.to_json() for u in self.units],
            "failures": [f.to_json() for f in self.failures],
            "not_run": {},
        }


def read_results(path: Path) -> Results:
    """The results of ``results.json`` (or ``.json.gz``) at ``path``; InputError naming the file when it
    cannot be read or is not an evaluation's results."""
    path = Path(path)
    try:
        raw = gzip.decompress(path.read_bytes()) if path.suffix == ".gz" else path.read_bytes()
        data = json.loads(raw)
    except (OSError, EOFError, ValueError) as e:  # missing, unreadable, not gzip, not JSON
        raise InputError(f"{path}: not the results of a sparself evaluation ({type(e).__name__}: {e})") from None
    try:
        return Results.from_json(data)
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise InputError(f"{path}: not the results of a sparself evaluation ({type(e).__name__}: {e})") from None
