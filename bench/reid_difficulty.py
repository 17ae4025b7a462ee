"""How hard cross-camera re-identification is in a prepared cache: top-1 accuracy of plain matchers.

A figure that describes the world, not a target to tune it to. Over a
`sianms prepare` cache (its detections, their ground-truth instances and ROI features) and
the dataroot it was prepared from (recorded in its manifest; ``--dataroot`` overrides):

- **query**: a car detection in camera A whose ground-truth car is also detected, as a car,
  in a contiguous camera B of the same sample, both boxes at least ``--min-height`` px tall.
  Both directions of every contiguous pair ask (A -> B and B -> A), so a car seen by two
  cameras gives two queries. Every row of the cache counts as a detection: the detector's,
  and in a training cache also the ground-truth boxes filled in for its misses.
- **candidates**: the car detections of camera B in its overlap strip with A, the rule
  siaNMS pairs by (:func:`sianms_cli.evaluation.matching.overlap_columns`: B's image columns
  whose rays at infinity A sees; a box counts when its horizontal extent meets that band),
  optionally at least ``--candidate-min-height`` px tall. A query whose true match is not a
  candidate (outside the strip) is counted apart and left out.
- **matchers** pick the candidate nearest to the query:

  - *mean colour*: the mean of the JPEG's sRGB values over the box (pixels whose centre lies
    in the box), compared by Euclidean distance in sRGB (0-255) and, second row, in CIELAB
    (D65) computed from that mean;
  - *siamese* (``--checkpoint``, a `sianms train siamese` run): the encoder's embeddings of the
    cache's ROI features, compared by the L2 distance siaNMS matches with.

- **top-1 accuracy** over the queries with at least two candidates. A tie at the smallest
  distance is credited 1/k when the true match is one of the k tied candidates (the
  expectation of picking among them at random), so the figure is deterministic and never
  favours a candidate order; the share of queries with a tie is printed beside it.
  Also printed: the share of queries with one candidate only, the mean number of candidates,
  and the chance level mean(1/n) over the queries with a choice.

torch is imported only with ``--checkpoint``.

    python bench/reid_difficulty.py sianms-demo/cache-val
    python bench/reid_difficulty.py sianms-demo/cache-val --checkpoint sianms-demo/siamese --json reid.json
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sianms_cli.data.cache import decode_roi_features, read_dataset, read_manifest
from sianms_cli.data.siamese import cache_feature_shape
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import write_json
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.sample_rigs import sample_rigs
from sianms_cli.nuscenes.sensors import read_image
from sianms_cli.evaluation.matching import in_columns, overlap_columns

DETECTION_COLUMNS = ["detection_id", "sample_token", "sample_data_token", "camera", "x1", "y1", "x2", "y2", "class",
                     "instance_token", "image_width", "image_height"]


@dataclass(frozen=True, eq=False)
class CacheDetections:
    """The cache's detections as D aligned arrays (every finished shard, shard-name order).

    Attributes:
        sample_data_token, camera, classes: (D,) str.
        sample: (D,) int64 index into ``sample_tokens``.
        sample_tokens: (S,) str, distinct.
        instance: (D,) int64 ground-truth instance code, -1 for none.
        boxes: (D, 4) float64 [x1, y1, x2, y2] pixels of the detection's image.
        image_size: (D, 2) int64 [W, H] of the image the detection was made on.
    """

    sample_data_token: np.ndarray
    camera: np.ndarray
    classes: np.ndarray
    sample: np.ndarray
    sample_tokens: np.ndarray
    instance: np.ndarray
    boxes: np.ndarray
    image_size: np.ndarray

    def __len__(self) -> int:
        return len(self.camera)

    @property
    def heights(self) -> np.ndarray:
        return self.boxes[:, 3] - self.boxes[:, 1]


@dataclass(frozen=True, eq=False)
class Queries:
    """Q queries and their K candidate rows, flattened (the rows of one query are contiguous).

    Attributes:
        detection: (Q,) detection row of each query (camera A).
        positive: (Q,) detection row of its true match (camera B).
        pair: (Q,) str "A>B", the camera asked and the camera searched.
        candidate_query: (K,) int64 query of each candidate row, non-decreasing.
        candidate_detection: (K,) detection row of each candidate (camera B).
        outside_strip: would-be queries left out because their true match is not a candidate.
    """

    detection: np.ndarray
    positive: np.ndarray
    pair: np.ndarray
    candidate_query: np.ndarray
    candidate_detection: np.ndarray
    outside_strip: int

    def __len__(self) -> int:
        return len(self.detection)

    @property
    def counts(self) -> np.ndarray:
        """(Q,) candidates per query (at least 1: the true match)."""
        return np.bincount(self.candidate_query, minlength=len(self)).astype(np.int64)


# --------------------------------------------------------------------------- reading


def cache_source(cache: Path, dataroot: str | None, version: str | None) -> tuple[Path, str]:
    """(dataroot, version) the cache was prepared from, from its manifest unless given."""
    manifest = read_manifest(cache)
    if manifest is None:
        raise DataFormatError(cache / "manifest.json", "not found: not a `sianms prepare` cache")
    if dataroot is None:
        dataroot = manifest.get("dataroot")
        if not isinstance(dataroot, str):
            raise DataFormatError(cache / "manifest.json", "no dataroot recorded; give --dataroot", field="dataroot")
    if version is None:
        version = manifest["config"].get("version")
        if not isinstance(version, str):
            raise DataFormatError(cache / "manifest.json", "no version recorded; give --version",
                                  field="config.version")
    return Path(dataroot), version


def _strings(table, name: str) -> np.ndarray:
    return table[name].fill_null("").to_numpy(zero_copy_only=False).astype(str)


def load_detections(cache: Path) -> CacheDetections:
    """The detections of every finished shard of ``cache`` (without their ROI features)."""
    table = read_dataset(cache, "detections", DETECTION_COLUMNS)
    sample_tokens, sample = np.unique(_strings(table, "sample_token"), return_inverse=True)
    instances = _strings(table, "instance_token")
    known, instance = np.unique(instances, return_inverse=True)
    instance = np.where(instances == "", -1, instance).astype(np.int64)
    boxes = np.stack([table[c].to_numpy() for c in ("x1", "y1", "x2", "y2")], axis=1).astype(np.float64)
    size = np.stack([table["image_width"].to_numpy(), table["image_height"].to_numpy()], axis=1).astype(np.int64)
    return CacheDetections(sample_data_token=_strings(table, "sample_data_token"), camera=_strings(table, "camera"),
                           classes=_strings(table, "class"), sample=sample.astype(np.int64),
                           sample_tokens=sample_tokens, instance=instance, boxes=boxes, image_size=size)


# --------------------------------------------------------------------------- queries


def _equal_key_pairs(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (i, j) with ``left[i] == right[j]``, ordered by i, then by j.

    Args:
        left: (L,) int64 keys; right: (R,) int64 keys.

    Returns:
        (left rows, right rows), each (M,) int64.
    """
    order = np.argsort(right, kind="stable")
    lo = np.searchsorted(right[order], left, side="left")
    hi = np.searchsorted(right[order], left, side="right")
    count = hi - lo
    left_rows = np.repeat(np.arange(len(left)), count)
    within = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    return left_rows, order[np.repeat(lo, count) + within]


def _rig_cameras(detections: CacheDetections, db: NuScenesDB) -> tuple[list, np.ndarray, np.ndarray]:
    """(rigs, (D,) rig of each detection, (D,) its camera's index in that rig, -1 when none)."""
    rigs, rig_of_sample = sample_rigs(db, detections.sample_tokens.tolist())
    rig = rig_of_sample[detections.sample]
    camera = np.full(len(detections), -1, dtype=np.int64)
    for r, camera_rig in enumerate(rigs):
        for c, channel in enumerate(camera_rig.channels):
            camera[(rig == r) & (detections.camera == channel)] = c
    return rigs, rig, camera


def build_queries(detections: CacheDetections, db: NuScenesDB, matched_class: str = "car",
                  min_height: float = 40.0, candidate_min_height: float = 0.0) -> Queries:
    """The queries and candidates of the module docstring, over every sample of the cache.

    Vectorised within each (rig, ordered contiguous pair); a dataset holds few rigs.
    """
    rigs, rig, camera = _rig_cameras(detections, db)
    heights = detections.heights
    cars = (detections.classes == matched_class) & (rig >= 0)
    with_instance = cars & (detections.instance >= 0)
    instances = int(detections.instance.max(initial=0)) + 1
    key = detections.sample * instances + detections.instance  # (sample, instance)
    parts: list[tuple[np.ndarray, ...]] = []
    outside = 0
    for r, camera_rig in enumerate(rigs):
        for first, second in camera_rig.contiguous_pairs:
            for a, b in ((first, second), (second, first)):
                strip = overlap_columns(camera_rig.intrinsics[b], tuple(camera_rig.image_sizes[b]),
                                        camera_rig.ego_to_cam[a, :3, :3] @ camera_rig.cam_to_ego[b, :3, :3],
                                        camera_rig.intrinsics[a], tuple(camera_rig.image_sizes[a]))
                in_a = with_instance & (rig == r) & (camera == a) & (heights >= min_height)
                in_b = with_instance & (rig == r) & (camera == b)
                asked, seen = np.flatnonzero(in_a), np.flatnonzero(in_b)
                i, j = _equal_key_pairs(key[asked], key[seen])  # one detection per (instance, camera)
                if len(np.unique(i)) != len(i):
                    raise SianmsError(f"the cache's detections hold two of one ground-truth instance in one "
                                      f"{camera_rig.channels[a]} image: not a `sianms prepare` cache?")
                asked, positive = asked[i], seen[j]
                keep = heights[positive] >= min_height
                asked, positive = asked[keep], positive[keep]
                candidate = cars & (rig == r) & (camera == b) & in_columns(detections.boxes, strip) & (
                    heights >= candidate_min_height)
                reachable = candidate[positive]
                outside += int((~reachable).sum())
                asked, positive = asked[reachable], positive[reachable]
                rows = np.flatnonzero(candidate)
                q, c = _equal_key_pairs(detections.sample[asked], detections.sample[rows])
                name = f"{camera_rig.channels[a]}>{camera_rig.channels[b]}"
                parts.append((asked, positive, np.full(len(asked), name, dtype=object), q, rows[c]))
    offsets = np.cumsum([0] + [len(part[0]) for part in parts])
    empty = np.zeros(0, dtype=np.int64)
    return Queries(
        detection=np.concatenate([p[0] for p in parts] + [empty]),
        positive=np.concatenate([p[1] for p in parts] + [empty]),
        pair=np.concatenate([p[2] for p in parts] + [np.zeros(0, dtype=object)]).astype(str),
        candidate_query=np.concatenate([p[3] + o for p, o in zip(parts, offsets)] + [empty]),
        candidate_detection=np.concatenate([p[4] for p in parts] + [empty]),
        outside_strip=outside)


# --------------------------------------------------------------------------- features


def box_mean_colours(image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Mean sRGB value of the pixels whose centre lies in each box.

    Args:
        image: (H, W, 3) uint8 RGB.
        boxes: (N, 4) [x1, y1, x2, y2] pixels; pixel (u, v) covers [u, u + 1) x [v, v + 1).

    Returns:
        (N, 3) float64 in 0-255. A box that holds no pixel centre takes the pixel just past
        its first edge; boxes are clipped to the image.
    """
    height, width = image.shape[:2]
    table = np.zeros((height + 1, width + 1, 3), dtype=np.int64)  # summed-area table
    table[1:, 1:] = image.astype(np.int64).cumsum(0).cumsum(1)
    # The first pixel whose centre k + 0.5 is at or past each edge: [x1, x2) holds k in [x1', x2').
    edge = np.ceil(np.asarray(boxes, dtype=np.float64) - 0.5).astype(np.int64)
    x1 = np.clip(edge[:, 0], 0, width - 1)
    y1 = np.clip(edge[:, 1], 0, height - 1)
    x2 = np.clip(np.maximum(edge[:, 2], x1 + 1), 1, width)
    y2 = np.clip(np.maximum(edge[:, 3], y1 + 1), 1, height)
    total = table[y2, x2] - table[y1, x2] - table[y2, x1] + table[y1, x1]
    return total / ((y2 - y1) * (x2 - x1))[:, None]


def mean_colours(db: NuScenesDB, detections: CacheDetections, rows: np.ndarray) -> np.ndarray:
    """(D, 3) mean sRGB (0-255) of the given detection rows, NaN for the others; each JPEG read once."""
    colours = np.full((len(detections), 3), np.nan)
    tokens, image_of, per_image = np.unique(detections.sample_data_token[rows], return_inverse=True,
                                            return_counts=True)
    by_image = np.split(rows[np.argsort(image_of, kind="stable")], np.cumsum(per_image)[:-1])
    for token, mine in zip(tokens.tolist(), by_image):
        image = read_image(db.data_path(token), token)
        expected = tuple(detections.image_size[mine[0]])
        if (image.shape[1], image.shape[0]) != expected:
            raise DataFormatError(db.data_path(token), f"image is {image.shape[1]}x{image.shape[0]}, the cache's "
                                  f"detections were made on {expected[0]}x{expected[1]}: another dataroot?",
                                  token=token)
        colours[mine] = box_mean_colours(image, detections.boxes[mine])
    return colours


def srgb_to_lab(srgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65 white, L in 0-100) of (N, 3) sRGB values in 0-255 (IEC 61966-2-1 and CIE 15)."""
    c = np.asarray(srgb, dtype=np.float64) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    to_xyz = np.array([[0.4124564, 0.3575761, 0.1804375],
                       [0.2126729, 0.7151522, 0.0721750],
                       [0.0193339, 0.1191920, 0.9503041]])
    xyz = linear @ to_xyz.T / np.array([0.95047, 1.0, 1.08883])
    epsilon, kappa = 216 / 24389, 24389 / 27
    f = np.where(xyz > epsilon, np.cbrt(xyz), (kappa * xyz + 16) / 116)
    return np.stack([116 * f[:, 1] - 16, 500 * (f[:, 0] - f[:, 1]), 200 * (f[:, 1] - f[:, 2])], axis=1)


def siamese_embeddings(cache: Path, checkpoint: str, device: str, detections: CacheDetections,
                       rows: np.ndarray) -> np.ndarray:
    """(D, d) embeddings of the given detection rows by a trained encoder, NaN for the others."""
    from sianms_cli.training.siamese import embed, load_encoder

    encoder, _ = load_encoder(checkpoint, device)
    column = read_dataset(cache, "detections", ["roi_feature"])["roi_feature"].take(rows)
    features = decode_roi_features(column, cache_feature_shape(cache), Path(cache) / "detections")
    embedding = np.full((len(detections), encoder.dim), np.nan)
    embedding[rows] = embed(encoder, features)
    return embedding


# --------------------------------------------------------------------------- scoring


def top1_credit(queries: Queries, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each query's top-1 credit under nearest-neighbour matching by Euclidean distance.

    Args:
        queries: Q queries with their candidate rows.
        features: (D, F) one vector per detection (finite for every query and candidate).

    Returns:
        ``(credit, tied)``: (Q,) float64, 1/k when the true match is among the k candidates at
        the smallest distance, else 0; (Q,) bool, more than one candidate at that distance.
    """
    if len(queries) == 0:
        return np.zeros(0), np.zeros(0, dtype=bool)
    query = queries.candidate_query
    difference = features[queries.candidate_detection] - features[queries.detection[query]]
    distance = np.sqrt((difference * difference).sum(axis=1))
    starts = np.flatnonzero(np.r_[True, query[1:] != query[:-1]])
    nearest = np.minimum.reduceat(distance, starts)
    at_nearest = distance == nearest[query]
    ties = np.bincount(query[at_nearest], minlength=len(queries))
    right = at_nearest & (queries.candidate_detection == queries.positive[query])
    credit = np.bincount(query[right], weights=1.0 / ties[query[right]], minlength=len(queries))
    return credit, ties > 1


def summary(queries: Queries, matchers: dict[str, np.ndarray]) -> dict[str, Any]:
    """The figures of the module docstring; ``matchers`` maps a name to its (D, F) features."""
    counts = queries.counts
    choice = counts >= 2
    chosen = int(choice.sum())

    def share(values: np.ndarray) -> float | None:
        return float(values.mean()) if len(values) else None

    results = {}
    for name, features in matchers.items():
        credit, tied = top1_credit(queries, features)
        results[name] = {"top1": share(credit[choice]), "tie_share": share(tied[choice])}
    return {
        "queries": len(queries),
        "queries_by_pair": {str(name): int(n) for name, n in zip(*np.unique(queries.pair, return_counts=True))},
        "queries_with_choice": chosen,
        "outside_strip": queries.outside_strip,
        "one_candidate_share": share(~choice),
        "mean_candidates": share(counts),
        "mean_candidates_with_choice": share(counts[choice]),
        "chance": share(1.0 / counts[choice]),
        "matchers": results,
    }


def difficulty(cache: str | Path, *, dataroot: str | None = None, version: str | None = None,
               matched_class: str = "car", min_height: float = 40.0, candidate_min_height: float = 0.0,
               checkpoint: str | None = None, device: str = "cpu") -> dict[str, Any]:
    """The whole measurement: the summary, with the settings that made it under ``config``."""
    cache = Path(cache)
    root, version = cache_source(cache, dataroot, version)
    db = NuScenesDB(root, version)
    detections = load_detections(cache)
    queries = build_queries(detections, db, matched_class, min_height, candidate_min_height)
    rows = np.unique(np.concatenate([queries.detection, queries.candidate_detection]))
    colours = mean_colours(db, detections, rows)
    lab = np.full_like(colours, np.nan)
    lab[rows] = srgb_to_lab(colours[rows])
    matchers = {"mean colour (sRGB)": colours, "mean colour (CIELAB)": lab}
    if checkpoint is not None:
        matchers["siamese (embedding L2)"] = siamese_embeddings(cache, checkpoint, device, detections, rows)
    config = {"cache": str(cache.resolve()), "dataroot": str(root.resolve()), "version": version,
              "class": matched_class, "min_height": min_height, "candidate_min_height": candidate_min_height,
              "checkpoint": None if checkpoint is None else str(Path(checkpoint).resolve()),
              "directions": "both (A>B and B>A)", "ties": "credited 1/k among k tied candidates"}
    return {"config": config, **summary(queries, matchers)}


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f} %"


def table_text(result: dict[str, Any]) -> str:
    """The printed report: the query figures, then one line per matcher."""
    config = result["config"]
    mean_all = result["mean_candidates"]
    mean_choice = result["mean_candidates_with_choice"]
    lines = [
        f"re-identification difficulty of {config['cache']}",
        f"  dataroot {config['dataroot']} ({config['version']}); class {config['class']}; "
        f"both boxes >= {config['min_height']:g} px; candidates >= {config['candidate_min_height']:g} px",
        f"queries: {result['queries']} ({result['outside_strip']} more left out: true match outside the strip)",
        f"  with one candidate only: {_percent(result['one_candidate_share'])}",
        "  mean candidates: " + ("n/a" if mean_all is None else f"{mean_all:.2f} (all)")
        + ("" if mean_choice is None else f", {mean_choice:.2f} (with a choice)"),
        f"  with a choice: {result['queries_with_choice']}, chance level mean(1/n) {_percent(result['chance'])}",
        "",
        f"{'matcher':<26} {'top-1':>8} {'ties':>8}",
    ]
    for name, figures in result["matchers"].items():
        lines.append(f"{name:<26} {_percent(figures['top1']):>8} {_percent(figures['tie_share']):>8}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("cache", help="a `sianms prepare` output folder")
    parser.add_argument("--dataroot", help="the dataset the cache was prepared from [default: its manifest's]")
    parser.add_argument("--version", help="its version folder [default: the manifest's config]")
    parser.add_argument("--class", dest="matched_class", default="car", help="detection class matched [car]")
    parser.add_argument("--min-height", type=float, default=40.0, help="query and true match box height, px [40]")
    parser.add_argument("--candidate-min-height", type=float, default=0.0, help="candidate box height, px [0]")
    parser.add_argument("--checkpoint", help="a `sianms train siamese` run folder or its checkpoint.pt")
    parser.add_argument("--device", default="cpu", help="torch device of the siamese encoder [cpu]")
    parser.add_argument("--json", type=Path, help="also write the figures and settings here")
    args = parser.parse_args(argv)
    try:
        result = difficulty(args.cache, dataroot=args.dataroot, version=args.version,
                            matched_class=args.matched_class, min_height=args.min_height,
                            candidate_min_height=args.candidate_min_height, checkpoint=args.checkpoint,
                            device=args.device)
        if args.json is not None:
            write_json(args.json, result)
    except SianmsError as error:
        print(f"error: {error}", file=sys.stderr)
        return error.exit_code
    print(table_text(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
