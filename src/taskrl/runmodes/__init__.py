"""How a run runs: registered run modes (in one process, offline, distributed).

- [`spec`][taskrl.runmodes.spec]: what a mode declares ([`RunMode`][taskrl.runmodes.spec.RunMode]);
- [`registry`][taskrl.runmodes.registry]: the modes by name, and the one a config runs in;
- [`build`][taskrl.runmodes.build]: a config's parts, as its mode needs them;
- one file per family of modes: ``in_process``, ``offline``, ``distributed``.
"""
