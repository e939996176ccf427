"""A face for the runtime's FAPs: a generated mesh with MPEG-4 feature points, its deformation by
raised-cosine zones of influence and a turning jaw, and exports (glTF 2.0, VRML97) and a viewer."""
