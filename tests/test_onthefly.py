"""On-the-fly training from fresh target draws, replicates, and their IoU uncertainty (issue #15)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from metraw.errors import MetrawError
from metraw.io.store import RawStore

PARAMS = Path(__file__).resolve().parents[1] / "params.yaml"


def _cfg(**kw):
    from metraw.segment.train import TrainConfig

    base = dict(epochs=2, learning_rate=3e-3, batch_size=2, crop_px=16, base_channels=4, depth=2, seed=0,
                test_fraction=0.34, replicates=2)
    base.update(kw)
    return TrainConfig(**base)


def test_store_target_is_the_emulated_one(stores):
    from metraw.segment.onthefly import store_target

    src, tgt, target = stores
    assert store_target(RawStore.open(tgt)).gsd_m == pytest.approx(target.gsd_m)
    with pytest.raises(MetrawError, match="no emulated images"):
        store_target(RawStore.open(src))


def test_on_the_fly_replicates_are_deterministic_and_scored(stores, tmp_path):
    from metraw.segment.evaluate import evaluate_store
    from metraw.segment.onthefly import train_store_on_the_fly
    from metraw.segment.train import CHECKPOINT, TIMINGS, TRAIN_METRICS, replicate_dirs

    from metraw.io.store import write_decoded_copy

    src, tgt, _ = stores
    # run b reads the source's decoded working copy (the workflow's rule decode_store): the same bytes, train.json
    # (which names the source) included
    copy = write_decoded_copy(src, tmp_path / "copy.zarr", progress=False).path
    for run, source in (("a", src), ("b", copy)):
        rec = train_store_on_the_fly(tgt, source, tmp_path / run, _cfg(), device="cpu", progress=False, codec_step=1.0)
    assert rec["source"] == str(src)
    assert rec["on_the_fly"] and rec["replicate_seeds"] == [0, 1] and rec["draws"] == 4 * 2
    for rel in (CHECKPOINT, TRAIN_METRICS, f"replicate-1/{CHECKPOINT}"):
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel
    written = json.loads((tmp_path / "a" / TRAIN_METRICS).read_text())
    assert not set(TIMINGS) & set(written) and written["codec_step"] == 1.0
    assert [p.name for p in replicate_dirs(tmp_path / "a")] == ["replicate-1"]
    # the two seeds train different networks
    assert (tmp_path / "a" / CHECKPOINT).read_bytes() != (tmp_path / "a" / "replicate-1" / CHECKPOINT).read_bytes()
    m = evaluate_store(tgt, tmp_path / "a", device="cpu", progress=False)
    assert m["split"] == "test" and m["n_images"] == 2  # the store's own test split: never-trained scenes
    assert [r["seed"] for r in m["replicates"]] == [0, 1] and m["replicates"][0]["iou"] == m["iou"]
    ious = [r["iou"] for r in m["replicates"]]
    assert m["iou_replicate_mean"] == pytest.approx(np.mean(ious))
    assert m["iou_replicate_sd"] == pytest.approx(np.std(ious, ddof=1))
    assert m["iou_replicate_se"] == pytest.approx(np.std(ious, ddof=1) / np.sqrt(2))
    assert {"true_objects", "found_objects", "object_f1"} <= set(m)


def test_aggregate_adds_the_seed_spread_to_the_test_image_error():
    from metraw.spec.aggregate import iou_measurement

    per_image = [{"tp": tp, "fp": 2.0, "fn": 1.0} for tp in (1.0, 3.0, 2.0, 4.0)]
    single = {"iou": 0.5, "per_image": per_image}
    iou, var = iou_measurement(single, "x")
    assert iou == 0.5 and var > 0
    rep = {**single, "iou_replicate_mean": 0.45, "iou_replicate_se": 0.03}
    iou_r, var_r = iou_measurement(rep, "x")
    assert iou_r == 0.45 and var_r == pytest.approx(var + 0.03**2)


def test_static_baseline_reuses_one_draw_and_on_the_fly_does_not(stores):
    from metraw.segment.onthefly import build_fields, draw_prepared

    src, _, target = stores
    field = build_fields(RawStore.open(src), [0], target, progress=False)[0]
    a, b = draw_prepared(field, 0, 0), draw_prepared(field, 0, 1)
    assert not np.array_equal(a.z, b.z)  # a new draw each epoch
    assert np.array_equal(a.z, draw_prepared(field, 0, 0).z)  # and the same one for the same (seed, epoch)


def _same_fields(a, b) -> bool:
    arrays = lambda f: [*f.field.values(), *(f.sat or {}).values(), f.sub_total, f.sub_count_y, f.sub_count_x]
    return a.index == b.index and a.target == b.target and all(
        np.array_equal(x, y) for x, y in zip(arrays(a), arrays(b), strict=True))


def test_fields_built_in_worker_processes_equal_the_in_process_ones(stores):
    from metraw import codec
    from metraw.segment.onthefly import build_fields
    from metraw.segment.pretrain import box_fields

    src, _, target = stores
    store = RawStore.open(src)
    threads = codec.THREADS
    one, two = (build_fields(store, [4, 0, 2], target, progress=False, workers=w) for w in (1, 2))
    assert [f.index for f in two] == [4, 0, 2] and all(_same_fields(a, b) for a, b in zip(one, two, strict=True))
    coarse = dataclasses.replace(target, focal_length_m=1.2)
    scenes, targets = [(store, 1, 7), (store, 3, 9)], [[target, coarse], [coarse]]
    one, two = (box_fields(scenes, targets, progress=False, workers=w) for w in (1, 2))
    assert [[f.index for f in fs] for fs in two] == [[7, 7], [9]]
    assert all(_same_fields(a, b) for fa, fb in zip(one, two, strict=True) for a, b in zip(fa, fb, strict=True))
    assert codec.THREADS == threads  # the workers' single codec thread is theirs only
    with pytest.raises(MetrawError, match="workers must be >= 1"):
        build_fields(store, [0], target, workers=0)


def test_prefetched_batches_train_the_same_network(stores, monkeypatch):
    from metraw.segment import train
    from metraw.segment.onthefly import build_fields, fit_draws

    src, _, target = stores
    fields = build_fields(RawStore.open(src), range(4), target, progress=False)
    states = []
    for depth in (0, 2):
        monkeypatch.setattr(train, "PREFETCH_BATCHES", depth)
        model, _ = fit_draws(fields, _cfg(epochs=2), "cpu", False, codec_step=1.0)
        states.append(model.state_dict())
    assert all(states[0][k].equal(states[1][k]) for k in states[0])


def test_draw_processes_train_the_same_network_and_leave_the_codec_threads(stores, monkeypatch):
    # draws made in 2 forked processes (fit_draws' draw_workers) against the training process's own: every draw has
    # its own seed and the crops are cut in batch order, so the network is the same tensor for tensor. Box fields
    # with payload batches (the pretraining's path: a chosen field per draw) and plain fields through the codec.
    from metraw import codec
    from metraw.segment import onthefly
    from metraw.segment.onthefly import _DRAWING, build_fields, fit_draws

    monkeypatch.setattr(onthefly, "DRAWS_AHEAD", 2)  # fewer than an epoch's batches: the window moves
    src, _, target = stores
    store = RawStore.open(src)
    plain = build_fields(store, range(4), target, progress=False)
    coarse = dataclasses.replace(target, focal_length_m=1.2)
    box = [list(pair) for pair in zip(plain, build_fields(store, range(4), coarse, progress=False))]
    keys = [[(0, math.log(t.focal_length_m)) for t in (target, coarse)] for _ in box]
    threads = codec.THREADS
    for fields, kw in ((box, dict(payload_keys=keys)), (plain, dict(codec_step=1.0, draws_per_epoch=2))):
        states, records = [], []
        for workers in (0, 2):
            model, rec = fit_draws(fields, _cfg(epochs=2), "cpu", False, draw_workers=workers, **kw)
            states.append(model.state_dict())
            records.append(rec)
        assert all(states[0][k].equal(states[1][k]) for k in states[0])
        assert records[0]["loss_per_epoch"] == records[1]["loss_per_epoch"]
        assert records[1]["draws"] == len(fields) * kw.get("draws_per_epoch", 1) * 2
    assert codec.THREADS == threads and not _DRAWING  # nothing of the training is left behind
    with pytest.raises(MetrawError, match="draw workers must be >= 0"):
        fit_draws(plain, _cfg(epochs=1), "cpu", False, draw_workers=-1)


def test_a_box_of_targets_trains_within_a_cfa_family_and_refuses_a_mix(stores):
    from metraw.segment.onthefly import build_fields, fit_draws

    src, _, target = stores
    store = RawStore.open(src)
    coarse = dataclasses.replace(target, focal_length_m=1.2)
    box = [list(pair) for pair in zip(build_fields(store, range(4), target, progress=False),
                                      build_fields(store, range(4), coarse, progress=False))]
    model, rec = fit_draws(box, _cfg(epochs=1), "cpu", False)
    assert rec["n_train"] == 4 and rec["draws"] == 4
    mono = build_fields(store, range(4), dataclasses.replace(target, cfa_pattern="mono"), progress=False)
    with pytest.raises(MetrawError, match="mix mono and colour-filter targets"):
        fit_draws([[a, b] for (a, _), b in zip(box, mono)], _cfg(epochs=1), "cpu", False)


def test_cli_on_the_fly_and_its_errors(stores, tmp_path, capsys):
    import yaml

    from metraw.cli import main

    src, tgt, _ = stores
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"training": {"profile": "tiny", "split_seed": 0, "test_fraction": 0.34,
                                                   "profiles": {"tiny": dict(epochs=1, batch_size=2, crop_px=16,
                                                                             base_channels=4, depth=2)}}}))
    assert main(["train", str(tgt), "--source", str(src), "--out", str(tmp_path / "m"), "--params", str(params),
                 "--replicates", "2"]) == 0
    assert "4 scenes drawn on the fly, 1 epoch(s), 2 replicate(s)" in capsys.readouterr().err
    assert (tmp_path / "m" / "replicate-1" / "model.pt").is_file()
    # a source that is not the store's (another image count): one line, nothing written
    with RawStore.create(tmp_path / "short.zarr") as s:
        s.append(RawStore.open(src)[0])
    assert main(["train", str(tgt), "--source", str(tmp_path / "short.zarr"), "--out", str(tmp_path / "m2"),
                 "--params", str(params)]) == 2
    assert "not emulated from that source" in capsys.readouterr().err
    assert not (tmp_path / "m2").exists()
    assert main(["train", str(tgt), "--codec-step", "1", "--out", str(tmp_path / "m3"), "--params", str(params)]) == 2
    assert "--codec-step applies to on-the-fly draws only" in capsys.readouterr().err
    assert main(["train", str(tgt), "--workers", "2", "--out", str(tmp_path / "m3"), "--params", str(params)]) == 2
    assert "--workers applies to on-the-fly draws only" in capsys.readouterr().err
    assert main(["train", str(tgt), "--source", str(src), "--workers", "0", "--out", str(tmp_path / "m3"),
                 "--params", str(params)]) == 2
    assert "--workers must be >= 1, got 0" in capsys.readouterr().err
    assert main(["train", str(tgt), "--draw-workers", "2", "--out", str(tmp_path / "m3"), "--params", str(params)]) == 2
    assert "--draw-workers applies to on-the-fly draws only" in capsys.readouterr().err
    assert main(["train", str(tgt), "--source", str(src), "--draw-workers", "-1", "--out", str(tmp_path / "m3"),
                 "--params", str(params)]) == 2
    assert "--draw-workers must be >= 0, got -1" in capsys.readouterr().err
    assert not (tmp_path / "m3").exists()


def test_a_store_of_the_test_split_alone_trains_and_scores_like_the_whole_store(stores, tmp_path, capsys):
    """`metraw emulate --images test` writes only the source's test split, byte-identical to those images of the
    whole store; on-the-fly training (which draws from the source) and its evaluation do not change with it."""
    import yaml

    from metraw.cli import main
    from metraw.segment.data import source_indices, split_indices
    from metraw.segment.evaluate import evaluate_store
    from metraw.segment.onthefly import train_store_on_the_fly
    from metraw.segment.train import CHECKPOINT, train_store

    src = stores[0]
    params = yaml.safe_load(PARAMS.read_text())
    params["training"]["test_fraction"] = 0.34
    pfile = tmp_path / "params.yaml"
    pfile.write_text(yaml.safe_dump(params))
    for images in ("all", "test"):
        assert main(["emulate", str(src), str(tmp_path / f"{images}.zarr"), "--params", str(pfile), "--point",
                     "focal_length_m=2.0", "--images", images, "--workers", "1"]) == 0
        assert f"({images})" in capsys.readouterr().out
    full, test = RawStore.open(tmp_path / "all.zarr"), RawStore.open(tmp_path / "test.zarr")
    _, test_idx = split_indices(6, 0.34, 0)
    assert len(full) == 6 and len(test) == len(test_idx) == 2
    assert source_indices(full)[0].tolist() == list(range(6)) and source_indices(full)[1] == 6
    assert source_indices(test)[0].tolist() == test_idx.tolist() and source_indices(test)[1] == 6
    for pos, i in enumerate(test_idx):  # image i uses seed (seed, i) in either store
        assert np.array_equal(test[pos].data, full[i].data) and test[pos].provenance == full[i].provenance
    # the first N of all images (--limit) stay a data set of their own, split over its own images
    assert main(["emulate", str(src), str(tmp_path / "first4.zarr"), "--params", str(pfile), "--point",
                 "focal_length_m=2.0", "--images", "all", "--limit", "4", "--workers", "1"]) == 0
    assert source_indices(RawStore.open(tmp_path / "first4.zarr"))[0].tolist() == [0, 1, 2, 3]
    assert source_indices(RawStore.open(tmp_path / "first4.zarr"))[1] == 4
    cfg = _cfg(replicates=1)
    for images in ("all", "test"):
        train_store_on_the_fly(tmp_path / f"{images}.zarr", src, tmp_path / f"m-{images}", cfg, device="cpu",
                               progress=False, codec_step=1.0)
    assert (tmp_path / "m-all" / CHECKPOINT).read_bytes() == (tmp_path / "m-test" / CHECKPOINT).read_bytes()
    m_full = evaluate_store(tmp_path / "all.zarr", tmp_path / "m-all", device="cpu", progress=False)
    m_test = evaluate_store(tmp_path / "test.zarr", tmp_path / "m-test", device="cpu", progress=False)
    assert m_full["split"] == m_test["split"] == "test" and m_test["n_images"] == 2
    assert [r["iou"] for r in m_full["per_image"]] == [r["iou"] for r in m_test["per_image"]]
    assert m_full["iou"] == m_test["iou"]
    # a model trained beside one store scores the other's test split too (the split is by source image)
    cross = evaluate_store(tmp_path / "test.zarr", tmp_path / "m-all", device="cpu", progress=False, split="test")
    assert cross["iou"] == m_full["iou"] and not cross["training_store"]
    # the store's own fixed images cannot train a model: they are the test set
    with pytest.raises(MetrawError, match="holds 2 of its source's 6 images"):
        train_store(tmp_path / "test.zarr", tmp_path / "m-fixed", cfg, device="cpu", progress=False)
    # a store of another split's test images (split seed 1: source images 0 and 4) lacks this split's: one
    # line, nothing written
    params["training"]["split_seed"] = 1
    pfile.write_text(yaml.safe_dump(params))
    assert main(["emulate", str(src), str(tmp_path / "other.zarr"), "--params", str(pfile), "--point",
                 "focal_length_m=2.0", "--images", "test", "--workers", "1"]) == 0
    assert source_indices(RawStore.open(tmp_path / "other.zarr"))[0].tolist() == [0, 4]
    with pytest.raises(MetrawError, match="lacks 2 of the 2 test images"):
        train_store_on_the_fly(tmp_path / "other.zarr", src, tmp_path / "m-other", cfg, device="cpu", progress=False)
    assert not (tmp_path / "m-other").exists()
    with pytest.raises(MetrawError, match="lacks 2 of the 2 test images"):
        evaluate_store(tmp_path / "other.zarr", tmp_path / "m-all", device="cpu", progress=False, split="test")


def _parameters(state):
    """The trained parameters of a state dict (batch-norm running statistics move whatever the learning rate)."""
    return {k: v for k, v in state.items() if not k.endswith(("running_mean", "running_var", "num_batches_tracked"))}


@pytest.fixture(scope="module")
def pretrained(stores, tmp_path_factory):
    """Two replicates pretrained on a focal-length box from the source's 4 training scenes and 2 extra scenes."""
    from metraw.scenes import generate_one
    from metraw.segment.pretrain import pretrain_stores

    src, _, target = stores
    root = tmp_path_factory.mktemp("pre")
    with RawStore.create(root / "extra.zarr") as s:
        for i in range(2):
            s.append(generate_one(i, 1, 256))
    for run in ("p", "q"):
        rec = pretrain_stores(src, lambda o: dataclasses.replace(target, **o), {"focal_length_m": [1.2, 2.0]},
                              root / run, _cfg(epochs=1), 2, [root / "extra.zarr"], device="cpu", progress=False)
    return root, rec


def test_box_points_change_one_parameter_log_uniform_in_its_range():
    from metraw.segment.pretrain import sample_box

    box = {"focal_length_m": [0.8, 2.0], "exposure_s": [1e-4, 5e-4], "diameter_m": [0.1, 0.5]}
    drawn = sample_box(box, 2000, 3, seed=7)
    assert drawn == sample_box(box, 2000, 3, seed=7) and drawn != sample_box(box, 2000, 3, seed=8)
    points = [o for per_scene in drawn for o in per_scene]
    assert len(drawn) == 2000 and all(len(per_scene) == 3 for per_scene in drawn) and all(len(o) == 1 for o in points)
    n = len(points)
    for name, (low, high) in box.items():
        u = np.array([math.log(o[name] / low) / math.log(high / low) for o in points if name in o])
        assert ((u >= 0) & (u < 1)).all()
        # each parameter a third of the points (binomial), its log uniform in the range: mean 1/2, variance 1/12
        assert abs(u.size - n / 3) < 4 * math.sqrt(n * 2 / 9)
        assert abs(u.mean() - 0.5) < 4 * math.sqrt(1 / 12 / u.size)
        assert abs(u.var() - 1 / 12) < 4 * math.sqrt(1 / 180 / u.size)
    for bad, message in (({}, "box is empty"), ({"diameter_m": [0.5, 0.1]}, "must have 0 < low < high")):
        with pytest.raises(MetrawError, match=message):
            sample_box(bad, 1, 1, 0)


def test_payload_batches_hold_one_payload_each_and_every_draw_once():
    from metraw.raw.sensor import rng_from_seed
    from metraw.segment.onthefly import payload_batches
    from metraw.segment.pretrain import payload_keys, sample_box

    box = {"focal_length_m": [0.8, 2.0], "exposure_s": [1e-4, 5e-4], "diameter_m": [0.1, 0.5]}
    overrides = sample_box(box, 1500, 4, seed=3)
    keys = payload_keys(box, overrides)
    assert keys[0][0] == (list(box).index(next(iter(overrides[0][0]))), math.log(next(iter(overrides[0][0].values()))))
    batches, chosen = payload_batches(keys, 2, 8, rng_from_seed(5))
    again, chosen_again = payload_batches(keys, 2, 8, rng_from_seed(5))
    assert all(np.array_equal(a, b) for a, b in zip(batches, again)) and np.array_equal(chosen, chosen_again)
    n = 1500 * 2
    # every draw exactly once, in batches of 8 (the last may be short)
    ids = np.concatenate(batches)
    assert np.array_equal(np.sort(ids), np.arange(n)) and len(batches) == math.ceil(n / 8)
    assert sorted(len(b) for b in batches)[1:] == [8] * (len(batches) - 1)
    # each batch a run of the sorted keys: one parameter, except where two parameters' runs meet (at most 2 batches)
    drawn = [[keys[j % 1500][chosen[j]] for j in b] for b in batches]
    assert sum(len({k[0] for k in d}) > 1 for d in drawn) <= len(box) - 1
    spans = sorted((min(d), max(d)) for d in drawn)
    assert all(hi <= lo_next for (_, hi), (lo_next, _) in zip(spans, spans[1:]))
    # a batch spans a small part of its parameter's log range (about 8 / its ~1000 draws of it)
    widths = [d[-1][1] - d[0][1] for d in map(sorted, drawn) if len({k[0] for k in d}) == 1]
    assert np.median(widths) < 0.05 * math.log(5)
    # the field each draw takes is uniform over its scene's 4 (binomial counts, 5 sigma)
    counts = np.bincount(chosen, minlength=4)
    assert np.all(np.abs(counts - n / 4) < 5 * math.sqrt(n * 3 / 16))
    # batch order is shuffled: not sorted by key
    assert spans != [(min(d), max(d)) for d in drawn]


def test_payload_batched_pretraining_differs_from_mixed_and_is_recorded(stores, pretrained, tmp_path):
    import torch

    from metraw.segment.pretrain import pretrain_stores
    from metraw.segment.train import CHECKPOINT

    src, _, target = stores
    root, rec = pretrained
    assert rec["batches"] == "payload" and rec["payload_batches"]
    mixed = pretrain_stores(src, lambda o: dataclasses.replace(target, **o), {"focal_length_m": [1.2, 2.0]},
                            tmp_path / "m", _cfg(epochs=1), 2, [root / "extra.zarr"], device="cpu", progress=False,
                            batches="mixed")
    assert mixed["batches"] == "mixed" and not mixed["payload_batches"]
    a = torch.load(root / "p" / CHECKPOINT, weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "m" / CHECKPOINT, weights_only=True)["state_dict"]
    assert max(float((a[k].float() - b[k].float()).abs().max()) for k in a) > 1e-4
    with pytest.raises(MetrawError, match="batches must be one of payload, mixed"):
        pretrain_stores(src, lambda o: dataclasses.replace(target, **o), {"focal_length_m": [1.2, 2.0]},
                        tmp_path / "x", _cfg(epochs=1), 2, device="cpu", progress=False, batches="sorted")
    assert not (tmp_path / "x").exists()


def test_pretraining_draws_the_training_and_extra_scenes_and_is_deterministic(stores, pretrained):
    from metraw.segment.pretrain import box_fields
    from metraw.segment.train import CHECKPOINT, TRAIN_METRICS

    src, _, target = stores
    store = RawStore.open(src)
    coarse = dataclasses.replace(target, focal_length_m=1.2)
    box = box_fields([(store, i, 10 + i) for i in range(2)], [[target, coarse], [coarse]], progress=False)
    assert [[f.target.focal_length_m for f in fields] for fields in box] == [[2.0, 1.2], [1.2]]
    assert [f.index for fields in box for f in fields] == [10, 10, 11]
    with pytest.raises(MetrawError, match="mixes mono"):
        box_fields([(store, 0, 0)], [[target, dataclasses.replace(target, cfa_pattern="mono")]], progress=False)
    root, rec = pretrained
    # the source's 4 training scenes (its 2 test scenes never drawn) and both extra scenes, in 2 replicates
    assert rec["n_train"] == 6 and len(rec["train_indices"]) == 4
    assert set(rec["test_indices"]).isdisjoint(rec["train_indices"]) and len(rec["test_indices"]) == 2
    assert rec["box"] == {"focal_length_m": [1.2, 2.0]} and rec["points_per_scene"] == 2
    assert rec["replicate_seeds"] == [0, 1]
    # trained across the box's ground sampling, not at one GSD: the range of the drawn payloads' packed GSDs
    from metraw.raw.cfa import cell_size
    from metraw.segment.pretrain import sample_box

    drawn = [o["focal_length_m"] for per in sample_box(rec["box"], 6, 2, rec["config"]["seed"]) for o in per]
    gsd = [dataclasses.replace(target, focal_length_m=f).gsd_m * cell_size(target.cfa_pattern) for f in drawn]
    assert rec["train_packed_gsd_m"] == pytest.approx([min(gsd), max(gsd)]) and min(gsd) < max(gsd)
    import torch

    assert torch.load(root / "p" / CHECKPOINT, weights_only=True)["train_packed_gsd_m"] == rec["train_packed_gsd_m"]
    for rel in (CHECKPOINT, TRAIN_METRICS, f"replicate-1/{CHECKPOINT}"):
        assert (root / "p" / rel).read_bytes() == (root / "q" / rel).read_bytes(), rel


def test_fine_tuning_starts_each_replicate_from_its_pretrained_replicate(stores, pretrained, tmp_path):
    import torch

    from metraw.segment.onthefly import train_store_on_the_fly

    src, tgt, _ = stores
    root, _ = pretrained
    pre = [_parameters(torch.load(root / "p" / rel, weights_only=True)["state_dict"])
           for rel in ("model.pt", "replicate-1/model.pt")]
    # at a vanishing learning rate the fine-tuned weights stay where replicate r's pretraining left them
    rec = train_store_on_the_fly(tgt, src, tmp_path / "ft", _cfg(epochs=1, learning_rate=1e-12), device="cpu",
                                 progress=False, init_dir=root / "p")
    assert rec["init"] == str(root / "p") and rec["fine_tuned"]
    for r, rel in enumerate(("model.pt", "replicate-1/model.pt")):
        tuned = _parameters(torch.load(tmp_path / "ft" / rel, weights_only=True)["state_dict"])
        assert max(float((tuned[k] - pre[r][k]).abs().max()) for k in tuned) < 1e-6
        assert max(float((tuned[k] - pre[1 - r][k]).abs().max()) for k in tuned) > 1e-3
    with pytest.raises(MetrawError, match="holds 2 pretrained replicate"):
        train_store_on_the_fly(tgt, src, tmp_path / "x", _cfg(replicates=3), "cpu", False, init_dir=root / "p")
    with pytest.raises(MetrawError, match="do not fit this network"):
        train_store_on_the_fly(tgt, src, tmp_path / "y", _cfg(depth=3), "cpu", False, init_dir=root / "p")
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_cli_pretrain_with_another_sensor_pattern(stores, tmp_path, capsys):
    """`metraw pretrain --cfa-pattern mono` draws the box with a mono sensor: a network of mono images (four planes
    of 2 x 2 pixels, as the Bayer one's four sites), which a Bayer point cannot fine-tune; an unknown pattern is one
    line, nothing written."""
    from metraw.cli import main

    src, tgt, _ = stores
    common = ["--params", str(PARAMS), "--epochs", "1", "--replicates", "1", "--points-per-scene", "1"]
    for pattern, sensor in (("mono", "mono"), (None, "bayer")):
        out = tmp_path / f"pre_{pattern}"
        assert main(["pretrain", str(src), "--out", str(out), *common,
                     *(["--cfa-pattern", pattern] if pattern else [])]) == 0
        captured = capsys.readouterr()
        assert json.loads(captured.out)["cfa_pattern"] == (pattern or "RGGB")
        assert f"; {pattern or 'RGGB'} sensor)" in captured.err
        record = json.loads((out / "train.json").read_text())
        assert record["in_channels"] == 4 and record["sensor"] == sensor
    assert main(["train", str(tgt), "--source", str(src), "--init", str(tmp_path / "pre_mono"), "--epochs", "1",
                 "--replicates", "1", "--out", str(tmp_path / "m"), "--params", str(PARAMS)]) == 2
    assert "was pretrained on mono images; this training sees bayer images" in capsys.readouterr().err
    assert main(["pretrain", str(src), "--out", str(tmp_path / "bad"), *common, "--cfa-pattern", "RGBW"]) == 2
    assert "unsupported CFA pattern 'RGBW'" in capsys.readouterr().err
    assert not (tmp_path / "m").exists() and not (tmp_path / "bad").exists()


def test_cli_pretrain_over_the_params_box_then_fine_tune(stores, tmp_path, capsys):
    import yaml

    from metraw.cli import main
    from metraw.segment.config import load_config

    src, tgt, _ = stores
    out = tmp_path / "pre"
    assert main(["pretrain", str(src), "--out", str(out), "--params", str(PARAMS), "--epochs", "1",
                 "--replicates", "1", "--points-per-scene", "2", "--batches", "mixed", "--draw-workers", "2",
                 "--batch-size", "3"]) == 0
    captured = capsys.readouterr()
    err = captured.err
    assert "5 scenes x 2 points of the box (focal_length_m, diameter_m, " in err and "1 replicate(s)" in err
    record = json.loads((out / "train.json").read_text())
    assert record["box"]["focal_length_m"] == [0.8, 2.0] and record["points_per_scene"] == 2
    # --batches overrides params.yaml's training.pretrain.batches (payload)
    assert record["batches"] == "mixed" and not record["payload_batches"]
    assert json.loads(captured.out)["batches"] == "mixed"
    # --batch-size overrides the profile's batch size for the pretraining only: the fine-tuning below keeps the profile's
    assert record["config"]["batch_size"] == 3 and "1 epoch(s) in batches of 3" in err
    assert main(["train", str(tgt), "--source", str(src), "--init", str(out), "--epochs", "1",
                 "--out", str(tmp_path / "m"), "--params", str(PARAMS)]) == 2
    assert "holds 1 pretrained replicate(s); 3 are asked for" in capsys.readouterr().err
    assert main(["train", str(tgt), "--source", str(src), "--init", str(out), "--epochs", "1", "--replicates", "1",
                 "--out", str(tmp_path / "m"), "--params", str(PARAMS), "--draw-workers", "2"]) == 0
    fine_tuned = json.loads((tmp_path / "m" / "train.json").read_text())
    assert fine_tuned["init"] == str(out) and fine_tuned["config"]["batch_size"] == load_config(PARAMS).batch_size != 3
    # --learning-rate overrides the profile's peak rate (training.pretrain.finetune_learning_rate in the workflow)
    rate = load_config(PARAMS).learning_rate / 8
    assert main(["train", str(tgt), "--source", str(src), "--init", str(out), "--epochs", "1", "--replicates", "1",
                 "--out", str(tmp_path / "m_lr"), "--params", str(PARAMS), "--learning-rate", str(rate)]) == 0
    gentle = json.loads((tmp_path / "m_lr" / "train.json").read_text())
    assert gentle["config"]["learning_rate"] == rate != fine_tuned["config"]["learning_rate"]
    assert gentle["config"] == {**fine_tuned["config"], "learning_rate": rate}
    import torch
    states = [torch.load(tmp_path / m / "model.pt", map_location="cpu", weights_only=False)["state_dict"]
              for m in ("m", "m_lr")]
    assert states[0].keys() == states[1].keys()
    assert any(not torch.equal(states[0][k], states[1][k]) for k in states[0])  # the rate reached the optimiser
    for bad in ("0", "-1e-3", "nan"):
        assert main(["train", str(tgt), "--source", str(src), "--init", str(out), "--epochs", "1", "--replicates",
                     "1", "--out", str(tmp_path / "m_bad"), "--params", str(PARAMS), f"--learning-rate={bad}"]) == 2
        assert "--learning-rate must be > 0" in capsys.readouterr().err
    assert not (tmp_path / "m_bad").exists()
    for bad, message in ((["--epochs", "0"], "--epochs must be >= 1"),
                         (["--points-per-scene", "0"], "--points-per-scene must be >= 1"),
                         (["--batch-size", "0"], "--batch-size must be >= 1"),
                         (["--workers", "0"], "--workers must be >= 1"),
                         (["--draw-workers", "-1"], "--draw-workers must be >= 0")):
        assert main(["pretrain", str(src), "--out", str(tmp_path / "bad"), "--params", str(PARAMS), *bad]) == 2
        assert message in capsys.readouterr().err
    assert main(["train", str(tgt), "--init", str(out), "--out", str(tmp_path / "m4"), "--params", str(PARAMS)]) == 2
    assert "--init applies to on-the-fly draws only" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists() and not (tmp_path / "m4").exists()
    # training.pretrain.batch_size in params sets the pretraining's batches (the schema takes it)
    params = yaml.safe_load(PARAMS.read_text())
    params["training"]["pretrain"]["batch_size"] = 2
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    assert main(["pretrain", str(src), "--out", str(tmp_path / "p2"), "--params", str(tmp_path / "p.yaml"),
                 "--epochs", "1", "--replicates", "1", "--points-per-scene", "1"]) == 0
    assert json.loads((tmp_path / "p2" / "train.json").read_text())["config"]["batch_size"] == 2
