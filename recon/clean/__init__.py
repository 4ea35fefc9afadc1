"""Real scanner conditions (beyond the paper, whose clouds were noise-free): outliers, head registration, denoising."""
