"""One key frame of `sianms prepare`: detections, ROI features, frustums and pairs as Parquet tables."""

from __future__ import annotations

import zlib

import numpy as np
import pyarrow as pa
import torch

from sianms_cli.data.frustums import extract_frustum
from sianms_cli.data.pairs import contiguous_pairs
from sianms_cli.data.schemas import FRUSTUMS_SCHEMA, PAIRS_SCHEMA, detections_schema, with_metadata
from sianms_cli.detection2d.association import associate
from sianms_cli.detection2d.backbones import STRIDE, build_backbone
from sianms_cli.detection2d.classes import detection_classes_of
from sianms_cli.detection2d.detections import Detections2D
from sianms_cli.detection2d.external import ExternalDetections
from sianms_cli.detection2d.ground_truth import camera_ground_truth
from sianms_cli.detection2d.roi_align import roi_align
from sianms_cli.detection2d.simulated import SimulatedDetectorConfig, simulate_detections
from sianms_cli.geometry.transforms import apply_transform, global_to_sensor, sensor_to_global, transform_boxes
from sianms_cli.geometry.transforms import invert_transform, make_transform
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.prepare.config import PrepareConfig


class Preparer:
    """The loaded state one process needs: dataset, detector, backbone."""

    def __init__(self, config: PrepareConfig, db: NuScenesDB | None = None) -> None:
        self.config = config
        self.db = db if db is not None else NuScenesDB(config.dataroot, config.version)
        self.external = (ExternalDetections(config.detector[5:], self.db, config.classes)
                         if config.detector.startswith("file:") else None)
        self.simulated = SimulatedDetectorConfig(classes=config.classes) if self.external is None else None
        self.backbone = build_backbone(config.backbone, config.weights, seed=config.seed)
        annotations = self.db.table("sample_annotation")
        self.ann_classes = detection_classes_of(self.db.annotation_category_names())
        self.ann_tokens = annotations.tokens
        self.ann_instances = annotations.column("instance_token")
        self.ann_center = annotations.column("translation")
        self.ann_size = annotations.column("size")
        self.ann_rotation = annotations.column("rotation")
        shape = (self.backbone.channels, config.roi_size, config.roi_size)
        metadata = {"sianms.roi_feature_shape": ",".join(map(str, shape)), "sianms.roi_feature_dtype": "<f2",
                    "sianms.backbone": config.backbone}
        self.feature_bytes = int(np.prod(shape)) * 2
        self.schemas = {
            "detections": with_metadata(detections_schema(self.feature_bytes), "detections", metadata),
            "frustums": with_metadata(FRUSTUMS_SCHEMA, "frustums"),
            "pairs": with_metadata(PAIRS_SCHEMA, "pairs"),
        }

    # -- LiDAR

    def _lidar_global(self, lidar_token: str) -> tuple[np.ndarray, np.ndarray]:
        """Key-frame sweep (+ earlier sweeps) in the global frame: (P, 3) xyz, (P, 2) intensity, time lag."""
        db = self.db
        key_time = db.get("sample_data", lidar_token)["timestamp"]
        xyz, extra = [], []
        token = lidar_token
        for _ in range(self.config.sweeps + 1):
            points = db.read_lidar(token)
            record = db.get("sample_data", token)
            rotation, translation, _ = db.calibration_of(token)
            ego_rotation, ego_translation = db.ego_pose_of(token)
            to_global = sensor_to_global(ego_rotation, ego_translation, rotation, translation)
            xyz.append(apply_transform(to_global, points[:, :3]))
            lag = (key_time - record["timestamp"]) / 1e6
            extra.append(np.stack([points[:, 3], np.full(len(points), lag)], axis=1))
            token = record["prev"]
            if not token:
                break
        return np.concatenate(xyz), np.concatenate(extra)

    # -- one sample

    def sample(self, scene_token: str, scene_name: str, sample_token: str, rig) -> dict[str, pa.Table]:
        db, config = self.db, self.config
        data = db.keyframe_data(sample_token)
        rows = db.sample_annotation_rows(sample_token)
        centers, sizes, rotations = self.ann_center[rows], self.ann_size[rows], self.ann_rotation[rows]
        if "LIDAR_TOP" in data:
            points_global, point_extra = self._lidar_global(data["LIDAR_TOP"])
            ego_rotation, ego_translation = db.ego_pose_of(data["LIDAR_TOP"])
            centers_ego = apply_transform(invert_transform(make_transform(ego_rotation, ego_translation)), centers)
            overlap = rig.overlap_pairs(centers_ego)  # (A, P)
        else:
            points_global, point_extra = np.zeros((0, 3)), np.zeros((0, 2))
            overlap = np.zeros((len(rows), len(rig.contiguous_pairs)), dtype=bool)
        pair_names = rig.pair_names
        det_cols: dict[str, list] = {name: [] for name in self.schemas["detections"].names}
        fru_cols: dict[str, list] = {name: [] for name in FRUSTUMS_SCHEMA.names}
        all_camera, all_instance, all_ids, all_source, all_class = [], [], [], [], []
        for cam, channel in enumerate(rig.channels):
            sd = data[channel]
            ego_rot, ego_t = db.ego_pose_of(sd)
            cal_rot, cal_t, intrinsic = db.calibration_of(sd)
            to_cam = global_to_sensor(ego_rot, ego_t, cal_rot, cal_t)
            center_cam, rotation_cam = transform_boxes(to_cam, centers, rotations)
            width, height = (int(v) for v in rig.image_sizes[cam])
            gt = camera_ground_truth(np.arange(len(rows)), self.ann_classes[rows], center_cam, sizes,
                                     rotation_cam, intrinsic, (width, height))
            if self.external is not None:
                detections = self.external.of(sd)
            else:
                rng = np.random.default_rng([config.seed, zlib.crc32(sd.encode())])
                detections = simulate_detections(gt, (width, height), rng, self.simulated)
            target = gt.subset(np.isin(gt.classes, config.classes))
            match, iou = associate(detections.boxes, target.boxes2d, config.iou_threshold,
                                   detections.classes, target.classes)
            source = ["detector"] * len(detections)
            if config.fills_missed:
                missed = np.setdiff1d(np.arange(len(target)), match[match >= 0])
                missed = missed[target.occlusion[missed] < 1.0]
                fill = Detections2D(target.boxes2d[missed], np.ones(len(missed)), target.classes[missed])
                detections = Detections2D.concatenate([detections, fill])
                match = np.concatenate([match, missed])
                iou = np.concatenate([iou, np.ones(len(missed))])
                source += ["ground_truth"] * len(missed)
            count = len(detections)
            if count == 0:
                continue
            features = self._roi_features(sd, detections.boxes)
            points_cam = apply_transform(to_cam, points_global)
            max_depth = np.inf if config.max_depth is None else config.max_depth
            for k in range(count):
                det_id = f"{sd}_{k:04d}"
                t = int(match[k])
                local = int(target.annotation_rows[t]) if t >= 0 else -1  # index into `rows`
                row = int(rows[local]) if t >= 0 else -1
                instance = str(self.ann_instances[row]) if t >= 0 else None
                box = detections.boxes[k]
                det_cols["detection_id"].append(det_id)
                det_cols["scene_token"].append(scene_token)
                det_cols["sample_token"].append(sample_token)
                det_cols["sample_data_token"].append(sd)
                det_cols["camera"].append(channel)
                det_cols["scene_name"].append(scene_name)
                det_cols["detection_index"].append(k)
                for j, name in enumerate(("x1", "y1", "x2", "y2")):
                    det_cols[name].append(float(box[j]))
                det_cols["score"].append(float(detections.scores[k]))
                det_cols["class"].append(str(detections.classes[k]))
                det_cols["source"].append(source[k])
                det_cols["image_width"].append(width)
                det_cols["image_height"].append(height)
                det_cols["instance_token"].append(instance)
                det_cols["annotation_token"].append(str(self.ann_tokens[row]) if t >= 0 else None)
                det_cols["iou"].append(float(iou[k]))
                det_cols["gt_truncation"].append(float(target.truncation[t]) if t >= 0 else None)
                det_cols["gt_occlusion"].append(float(target.occlusion[t]) if t >= 0 else None)
                det_cols["gt_distance"].append(float(target.distance[t]) if t >= 0 else None)
                det_cols["overlap_pairs"].append(
                    [pair_names[p] for p, (a, b) in enumerate(rig.contiguous_pairs)
                     if t >= 0 and overlap[local, p] and cam in (a, b)])
                det_cols["roi_feature"].append(features[k])
                frustum = extract_frustum(
                    points_cam, point_extra, box, intrinsic,
                    target.center_cam[t] if t >= 0 else None, target.size[t] if t >= 0 else None,
                    target.rotation_cam[t] if t >= 0 else None, config.min_depth, max_depth)
                for name, value in (("detection_id", det_id), ("scene_token", scene_token),
                                    ("sample_token", sample_token), ("sample_data_token", sd),
                                    ("camera", channel), ("class", str(detections.classes[k])),
                                    ("score", float(detections.scores[k])), ("source", source[k]),
                                    ("instance_token", instance), ("rot_angle", frustum.rot_angle),
                                    ("num_points", len(frustum.points))):
                    fru_cols[name].append(value)
                fru_cols["x"].append(frustum.points[:, 0].astype(np.float32))
                fru_cols["y"].append(frustum.points[:, 1].astype(np.float32))
                fru_cols["z"].append(frustum.points[:, 2].astype(np.float32))
                fru_cols["intensity"].append(frustum.extra[:, 0].astype(np.float32))
                fru_cols["time_lag"].append(frustum.extra[:, 1].astype(np.float32))
                fru_cols["label"].append(frustum.labels)
                b = frustum.box
                fru_cols["box_center_cam"].append(None if b is None else b["center_cam"].astype(np.float32))
                fru_cols["box_size"].append(None if b is None else b["size"].astype(np.float32))
                fru_cols["box_rotation_cam"].append(None if b is None else b["rotation_cam"].astype(np.float32))
                fru_cols["box_heading_cam"].append(None if b is None else b["heading_cam"])
                fru_cols["box_center_frustum"].append(None if b is None else b["center_frustum"].astype(np.float32))
                fru_cols["box_heading_frustum"].append(None if b is None else b["heading_frustum"])
                all_camera.append(cam)
                all_instance.append(instance or "")
                all_ids.append(det_id)
                all_source.append(source[k])
                all_class.append(str(detections.classes[k]))
        pair_cols: dict[str, list] = {name: [] for name in PAIRS_SCHEMA.names}
        local_of_instance = {str(self.ann_instances[r]): i for i, r in enumerate(rows.tolist())}
        for number, ref, pos in contiguous_pairs(np.array(all_camera, dtype=np.int64),
                                                 np.array(all_instance, dtype=str), rig.contiguous_pairs):
            a, b = rig.contiguous_pairs[number]
            for name, value in (("scene_token", scene_token), ("sample_token", sample_token),
                                ("instance_token", all_instance[ref]), ("class", all_class[ref]),
                                ("pair", pair_names[number]), ("camera_a", rig.channels[a]),
                                ("camera_b", rig.channels[b]), ("reference_detection_id", all_ids[ref]),
                                ("positive_detection_id", all_ids[pos]), ("reference_source", all_source[ref]),
                                ("positive_source", all_source[pos]),
                                ("center_in_overlap", bool(overlap[local_of_instance[all_instance[ref]], number]))):
                pair_cols[name].append(value)
        return {
            "detections": pa.table(det_cols, schema=self.schemas["detections"]),
            "frustums": pa.table(fru_cols, schema=self.schemas["frustums"]),
            "pairs": pa.table(pair_cols, schema=self.schemas["pairs"]),
        }

    def _roi_features(self, sd: str, boxes: np.ndarray) -> list[bytes]:
        image = self.db.read_image(sd)
        features, (sx, sy) = self.backbone.features(image)
        scaled = torch.as_tensor(boxes * np.array([sx, sy, sx, sy]), dtype=torch.float64)
        pooled = roi_align(features, [scaled], self.config.roi_size, 1.0 / STRIDE,
                           self.config.sampling_ratio, aligned=True)
        array = pooled.to(torch.float16).numpy().astype("<f2")
        return [array[k].tobytes() for k in range(len(array))]
