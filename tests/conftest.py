import atexit
import os
import shutil
import tempfile

import torch
from hypothesis import settings

# Two cores: keep intra-op threads predictable so tests do not oversubscribe the machine.
torch.set_num_threads(1)
os.environ.setdefault("MPLBACKEND", "Agg")
# compiled graphs, and the markers of shapes compiled before (which make `--compile auto` expect a later run's shorter
# compile), in a folder of this session: the suite chooses as on a fresh machine, whatever the user's cache holds
if "TORCHINDUCTOR_CACHE_DIR" not in os.environ:
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp(prefix="taskrl-test-compile-")
    atexit.register(shutil.rmtree, os.environ["TORCHINDUCTOR_CACHE_DIR"], ignore_errors=True)

# Property tests draw the same examples on every run: a CI gate that fails must fail again on rerun.
settings.register_profile("taskrl", derandomize=True)
settings.load_profile("taskrl")
