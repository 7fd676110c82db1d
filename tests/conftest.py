import os

import torch

# Two cores: keep intra-op threads predictable so tests do not oversubscribe the machine.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")
