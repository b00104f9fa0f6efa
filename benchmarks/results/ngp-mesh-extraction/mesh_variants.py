"""Mesh extraction variants of ngp runs (the ad hoc script behind benchmarks/RESULTS.md, "ngp mesh extraction"):
    python mesh_variants.py OUT.json RUN [RUN ...]   (the 2x rows: plain 10, fill 10, s1 10.0, s1.5 10.0 only)
CD and IoU against the ground truth, the mean over runs. The silhouette helper was tried and not used."""
import sys, warnings, json
warnings.filterwarnings("ignore")
import numpy as np, torch
torch.set_num_threads(1)
from va_plugin.cli.run import load_run
from va_plugin.export.mesh import extract_mesh
from va_plugin.eval.evaluate import ground_truth_mesh_path, load_mesh, FSCORE_THRESHOLD
from va_plugin.eval.geometry import geometry_metrics
from va_plugin.data.scenes.raycast import MeshRenderer

def silhouette_iou(mesh, dm):
    cams = dm.cameras
    r = MeshRenderer(mesh, lambda h: np.zeros((len(h.points), 3), np.float32))
    ious = []
    for i in range(dm.masks.shape[0]):
        t, _, _ = r.cast(*r.pixel_rays(cams, i))
        hit = np.isfinite(t).reshape(cams.height, cams.width)
        m = dm.masks[i].reshape(cams.height, cams.width).numpy() > 0.5
        ious.append((hit & m).sum() / max((hit | m).sum(), 1))
    return float(np.mean(ious))

rows = {}
out_json = sys.argv[1]
for run in sys.argv[2:]:
    pipeline, state = load_run(run, device="cpu")
    model = pipeline.model
    dm = pipeline.datamanager
    gt = load_mesh(ground_truth_mesh_path(pipeline, None))
    cell = 2 * float(model.scene.scene_radius) / 127
    variants = {"plain 10": (10, 0, False), "fill 10": (10, 0, True), "plain 5": (5, 0, False), "fill 5": (5, 0, True),
                "s0.5 10.0": (10.0, 0.5, True), "s1 10.0": (10.0, 1.0, True), "s1 5.0": (5.0, 1.0, True),
                "s1.5 10.0": (10.0, 1.5, True), "s1.5 5.0": (5.0, 1.5, True)}
    out, sil = {}, {}
    for name, (th, k, fill) in variants.items():
        model.config.density_threshold = th; model.config.mesh_smoothing = k * cell; model.fill_mesh_cavities = fill
        m = extract_mesh(model, resolution=128, with_color=False)
        g = geometry_metrics(m, gt, n_samples=100000, threshold=FSCORE_THRESHOLD)
        out[name] = (g["chamfer_distance"], g["volume_iou"], m.area / gt.area)
    rows[run] = {"metrics": out}
    print(run, {k: tuple(round(x, 4) for x in v) for k, v in out.items()}, flush=True)
json.dump(rows, open(out_json, "w"), indent=1)
names = list(next(iter(rows.values()))["metrics"].keys())
base = np.array([rows[r]["metrics"]["plain 10"][0] for r in rows])
for n in names:
    cd = np.array([rows[r]["metrics"][n][0] for r in rows]); iou = np.array([rows[r]["metrics"][n][1] for r in rows])
    area = np.array([rows[r]["metrics"][n][2] for r in rows])
    print(f"{n:24s} CD {cd.mean():.5f} ratio {np.exp(np.log(cd/base).mean()):.3f} better {int((cd<base).sum())}/{len(cd)}  IoU {iou.mean():.3f}  area/gt {area.mean():.2f}")
