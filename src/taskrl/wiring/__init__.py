"""The layer below [`taskrl.run`][taskrl.run]: what a run is made of and how its pieces are put together.

- [`parts`][taskrl.wiring.parts]: a run's envs, agent, evaluator and relabeller (`RunParts`);
- [`stored_data`][taskrl.wiring.stored_data]: datasets and another run's replay into the replay, and its size;
- [`checkpoints`][taskrl.wiring.checkpoints]: writing and restoring a run's checkpoints;
- [`calls`][taskrl.wiring.calls]: the settings and run directory of one call of ``train``.

How a run runs (in one process, offline, distributed) is a registered run mode, above this layer:
[`taskrl.runmodes`][taskrl.runmodes] (with [`build_parts`][taskrl.assembly.build_parts], a config's parts for its mode).
Everything env- or algorithm-specific comes from the registries: this package names no environment
and no algorithm.
"""
