"""diffstir-pairs and diffstir-train-rectifier on their default configurations, into a temporary out
(docs/acceptance.md)."""

from __future__ import annotations

import hashlib
import json

import pytest
from acceptance_commands import ROOT, full_only, ok, run

pytestmark = pytest.mark.acceptance
SHIPPED = ROOT / "checkpoints" / "rectifier" / "rectifier.ckpt"


def test_train_rectifier_trains_into_out_and_leaves_the_shipped_model(tmp_path):
    shipped = hashlib.sha256(SHIPPED.read_bytes()).hexdigest()
    ok(run("diffstir-train-rectifier", f"out={tmp_path / 'rectifier'}", cwd=ROOT, timeout=900))
    assert (tmp_path / "rectifier" / "rectifier.ckpt").is_file()
    card = json.loads((tmp_path / "rectifier" / "card.json").read_text())
    assert card  # the card names command, data and metrics
    assert hashlib.sha256(SHIPPED.read_bytes()).hexdigest() == shipped


@full_only
def test_pairs_makes_a_shard_and_collects_it(tmp_path):
    ok(run("diffstir-pairs", "out=pairs", cwd=tmp_path, timeout=3600))  # shard 0 of 25
    collected = run("diffstir-pairs", "collect=true", "out=pairs", cwd=tmp_path, timeout=600)
    # docs/rectifier.md: collect writes what the shards hold and exits non-zero, in one line, while any is missing
    assert collected.returncode == 1 and "Traceback" not in collected.stderr
    assert collected.stderr.strip().splitlines() == [
        f"incomplete: shards {list(range(1, 25))} lack pairs (failed fluids: []); rerun their shards to resume"]
    manifest = json.loads((tmp_path / "pairs" / "manifest.json").read_text())
    lines = (tmp_path / "pairs" / "pairs.jsonl").read_text().splitlines()
    assert not manifest["complete"] and manifest["pairs"] == len(lines) > 0
    assert manifest["expected_pairs"] == 2500


@full_only
def test_pairs_with_the_3d_truth_makes_a_shard(tmp_path):
    pytest.importorskip("skfem")
    ok(run("diffstir-pairs", "lab/sim@truth=fe3d", "pairs/design=truth3d", "pairs.design.fluids_per_shard=1",
           "out=pairs", cwd=tmp_path, timeout=3600))  # one fluid of shard 0, the design's sensors
    lines = [json.loads(x) for x in (tmp_path / "pairs" / "shards" / "shard-0000.jsonl").read_text().splitlines()]
    assert len(lines) == 10 and {p["truth_config"]["kind"] for p in lines} == {"fe3d"}
    # the design's viscosities start at 0.1 Pa s; a regularised law meets its drawn target within 1e-3
    assert all(p["preliminary_viscosity"] > 0 and p["reference_viscosity"] >= 0.1 * (1 - 1e-3) for p in lines)
