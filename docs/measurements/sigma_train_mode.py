"""Pre-training runs policy.train(), which also puts the frozen sigma network's sparse-VD
layers in their noisy (training) mode. Measure what that changes: VD state pre-training on the shipped reach sets
(2000/4000/8000 samples, Sigma 0.5, demo seed 0), pre-training seeds 0-2, as today and with sigma kept in eval mode."""

import json
import sys
import time
import torch
import vdtutorial.pretrain as pre
from vdtutorial.demos import Demos, demo_path
from vdtutorial.pretrain import PretrainConfig, pretrain

torch.set_num_threads(1)
orig = pre.make_policy


def sigma_eval_policy(*a, **k):
    p = orig(*a, **k)
    base_train = p.train

    def train(mode=True):
        base_train(mode)
        p.sigma.eval()
        return p

    p.train = train
    return p


rows = []
for n in (2000, 4000, 8000):
    demos = Demos.load(demo_path("reach", n, 0.5, 0))
    for seed in (0, 1, 2):
        out = {}
        for variant in ("today", "sigma_eval"):
            pre.make_policy = orig if variant == "today" else sigma_eval_policy
            start = time.process_time()
            policy, history = pretrain(demos, PretrainConfig(reg="vd"), seed=seed, progress=False)
            out[variant] = (policy, history[-1], time.process_time() - start)
        pre.make_policy = orig
        (a, ha, ta), (b, hb, tb) = out["today"], out["sigma_eval"]
        diff = max((x - y).abs().max().item() for x, y in zip(a.mu.parameters(), b.mu.parameters()))
        row = {
            "samples": n,
            "seed": seed,
            "val_mse_today": ha["val_mse"],
            "val_mse_sigma_eval": hb["val_mse"],
            "pruned_today": ha["weights_pruned"],
            "pruned_sigma_eval": hb["weights_pruned"],
            "max_abs_mu_param_diff": diff,
            "cpu_s": ta + tb,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
json.dump(rows, open(sys.argv[1], "w"), indent=1)
