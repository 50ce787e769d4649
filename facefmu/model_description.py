"""What pythonfmu's modelDescription.xml leaves out, added: units, bounds, dependencies.

* UnitDefinitions for mm, s, N, deg and the dimensionless "1"; unit, min and max on the variables;
* ModelStructure: every output declared with dependencies="" (outputs change only in
  doStep: no direct feedthrough), in Outputs and in InitialUnknowns;
* needsExecutionTool="false" (the FMU runs in the importer's Python).
"""

from xml.etree.ElementTree import Element, SubElement

from solver.face.jaw import JAW_RANGES, JAW_UNITS

UNITS = {"mm": {"m": "1", "factor": "0.001"}, "s": {"s": "1"},
         "deg": {"rad": "1", "factor": "0.017453292519943295"},
         "N": {"kg": "1", "m": "1", "s": "-2"}, "1": {}}

# name -> attributes of the type element (Real, Integer)
ATTRIBUTES = {
    **{m: {"unit": "1", "min": "0", "max": "1"}
       for m in ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")},
    "lip_aperture": {"unit": "mm", "min": "0"},
    "lip_protrusion": {"unit": "mm"},
    "lip_width": {"unit": "mm", "min": "0"},
    "upper_lip_protrusion": {"unit": "mm"},
    "lower_lip_protrusion": {"unit": "mm"},
    "contact_force": {"unit": "N", "min": "0"},
    "incisor_opening": {"unit": "mm", "min": "0"},
    **{name: {"unit": JAW_UNITS[name], "min": f"{lo:g}", "max": f"{hi:g}"}
       for name, (lo, hi) in JAW_RANGES.items()},
    "newton_iterations": {"min": "0"},
    "substeps": {"min": "0"},
    "tolerance": {"unit": "mm", "min": "1e-12"},
    "max_substep": {"unit": "s", "min": "1e-9"},
    "rom_full_time": {"unit": "s", "min": "0"},
}


def _unit_definitions():
    defs = Element("UnitDefinitions")
    for name, base in UNITS.items():
        unit = SubElement(defs, "Unit", {"name": name})
        SubElement(unit, "BaseUnit", {k: v for k, v in base.items() if k != "factor"}
                   | ({"factor": base["factor"]} if "factor" in base else {}))
    return defs


def extend_model_description(root):
    """Modify pythonfmu's XML element tree in place and return it."""
    cosim = root.find("CoSimulation")
    cosim.set("needsExecutionTool", "false")
    root.insert(list(root).index(cosim) + 1, _unit_definitions())
    outputs = []
    for index, var in enumerate(root.find("ModelVariables"), start=1):
        typed = var[0]
        for key, value in ATTRIBUTES.get(var.get("name"), {}).items():
            typed.set(key, value)
        if var.get("causality") == "output":
            outputs.append(index)
    structure = root.find("ModelStructure")
    for child in list(structure):
        structure.remove(child)
    if outputs:
        out = SubElement(structure, "Outputs")
        init = SubElement(structure, "InitialUnknowns")
        for i in outputs:
            SubElement(out, "Unknown", {"index": str(i), "dependencies": ""})
            SubElement(init, "Unknown", {"index": str(i), "dependencies": ""})
    return root
