"""The application: scenes (TOML files and the built-in ones), fidelity presets,
Simulation (a scene's run: inputs, steps, outputs, state), open_simulation (the full or
the reduced model of a scene), export, plots and parallel sweeps."""
