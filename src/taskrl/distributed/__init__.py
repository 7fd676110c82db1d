"""Distributed off-policy training (``--distributed``): collectors, a replay, Bellman updaters and a trainer.

- ``settings``: the ``cluster`` section of a run's config;
- ``roles``: `Collector` and `BellmanUpdater`, plain classes that also run as Ray actors;
- ``limiter``: the update-to-data limiter;
- ``pools``: the interface the trainer calls roles through (in this process, or on Ray);
- ``loop``: the trainer's loop (the replay lives in the trainer's process);
- ``actors``: the Ray shell, the only module here that imports Ray (the ``distributed`` extra).

See docs/distributed.md.
"""
