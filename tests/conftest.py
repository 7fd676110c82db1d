import os

import torch
from hypothesis import settings

# Two cores: keep intra-op threads predictable so tests do not oversubscribe the machine.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")

# Property tests draw the same examples on every run: a CI gate that fails must fail again on rerun.
settings.register_profile("taskrl", derandomize=True)
settings.load_profile("taskrl")
