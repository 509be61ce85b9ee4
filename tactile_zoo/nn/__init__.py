"""Building blocks shared by the models: LIF neurons, graph convolution over frames, attention, T-GCN."""
