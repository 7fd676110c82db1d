"""How a run runs: registered run modes (in one process, offline, distributed).

- :mod:`~taskrl.runmodes.spec`: what a mode declares (:class:`~taskrl.runmodes.spec.RunMode`);
- :mod:`~taskrl.runmodes.registry`: the modes by name, and the one a config runs in;
- :mod:`~taskrl.runmodes.build`: a config's parts, as its mode needs them;
- one file per family of modes: ``in_process``, ``offline``, ``distributed``.
"""
