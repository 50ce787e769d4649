"""The face: anatomies (the procedural generic face, the ANSYS reference face), muscles
and their activations, activation stiffening, the cables, lip and teeth contact, the jaw,
and the lip measures; solver.face.face_model.FaceModel puts them on a core Model."""
