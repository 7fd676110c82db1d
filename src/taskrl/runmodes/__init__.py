"""How a run runs: registered run modes (in one process, offline, distributed).

- [`spec`][taskrl.runmodes.spec]: what a mode declares ([`RunMode`][taskrl.runmodes.spec.RunMode]);
- [`registry`][taskrl.runmodes.registry]: the modes by name, and the one a config runs in;
- one file per family of modes: ``in_process``, ``offline``, ``distributed``; each mode's ``check`` says what it asks of a
  run's settings. A run's parts are built for its mode by [`build_parts`][taskrl.assembly.build_parts].
"""
