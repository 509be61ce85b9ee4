"""tactile-zoo's performance suite: each benchmark times a fast path and its naive counterpart in the same process.

Run everything with ``python -m benchmarks.run`` (``make benchmarks``); see benchmarks/README.md. Absolute times on a
shared machine drift; the ratios of side-by-side medians are what the suite reports.
"""

#: benchmark name -> module (under ``benchmarks``), in the order ``benchmarks.run`` runs them
BENCHMARKS = {
    "lif": "lif",
    "graph_conv": "graph_conv",
    "sgnet_epoch": "sgnet_epoch",
    "sgnet_event": "sgnet_event",
    "sgnet_reference": "sgnet_reference",
    "epoch_all_models": "epoch_all_models",
    "gpu_epoch": "gpu_epoch",
    "inference": "inference",
    "streaming_latency": "streaming_latency",
    "export_latency": "export_latency",
    "scaling": "scaling",
    "bench_wall": "bench_wall",
    "progress_overhead": "progress_overhead",
    "dcnn_memory": "dcnn_memory",
    "predict_memory": "predict_memory",
    "multibarrel_cost": "multibarrel_cost",
    "vs_pinned": "vs_pinned",
    "profile_models": "profile_models",
    "grid_size": "grid_size",
}
