"""Scenes built in code for benchmarks and tests, as dicts for solver.app.scene.parse_scene.

    sim = Simulation(parse_scene(gesture(0.05)), level="coarse", half=True)

gesture: the lip gesture with contact of benchmarks/fast_path.py. Transient, OOP 0 -> 1
and RIS 0 -> 0.5 over 0-0.15 s, held to the end; lip and teeth contact on; lip aperture
and protrusion recorded every 10 ms; at the `balanced` fidelity preset (solver.app.fidelity).
"""

DURATION = 0.3          # s: the benchmark's gesture


def gesture(duration=DURATION, contact="both"):
    """The lip gesture over duration (s); contact: the contact terms built ('both',
    'teeth', 'lips', 'none')."""
    def ramp(m, to):
        return {"muscle": m, "kind": "ramp", "start": 0.0, "end": 0.15, "to": to}
    return {"scene": {"name": "fast_path_gesture", "analysis": "transient",
                      "duration": duration, "fidelity": "balanced",
                      "description": "OOP + RIS rounding with lip and teeth contact"},
            "muscles": {"driven": ["OOP", "RIS"]},
            "effects": {"lip_contact": contact in ("both", "lips"),
                        "teeth_contact": contact in ("both", "teeth")},
            "outputs": {"record": ["lip_aperture", "lip_protrusion"], "interval": 0.01},
            "schedule": [ramp("OOP", 1.0), ramp("RIS", 0.5)]}
