"""The finite element layer: meshes and geometries, quadrature, Lagrange spaces, sparse assembly."""
