"""The script behind gso10-l2-neus.jsonl: each run's held-out views (all 12) scored with the learned inv_s
multiplied by each factor. It scales inv_s by patching the model, which for novel views renders what the
`render_sharpness` option (and `va-eval --render-sharpness K`) renders (tests/models/test_neus.py checks
that equality). Usage: python measure.py RUN[,RUN...] 1.5,2 OUT.jsonl
"""
import sys, json, numpy as np, torch
from pathlib import Path
from va_plugin.cli.run import load_run
from va_plugin.eval.evaluate import image_metrics
torch.set_num_threads(1)
out = open(sys.argv[3], "a")
for run in sys.argv[1].split(","):
    pipeline, state = load_run(Path(run), device="cpu")
    v = pipeline.model.variance
    orig = v.inv_s
    for k in [float(x) for x in sys.argv[2].split(",")]:
        v.inv_s = (lambda k=k: orig() * k)
        s = image_metrics(pipeline, progress=False)
        rec = dict(run=run, scene=Path(run).parts[4], factor=k, inv_s=float(orig().detach()), psnr=s["psnr"], ssim=s["ssim"], lpips=s["lpips"], views=s["image_params"]["views"])
        print(rec, flush=True); out.write(json.dumps(rec) + "\n"); out.flush()
