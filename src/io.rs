//! Mesh and load file reading and writing (OBJ, loads JSON), with atomic writes.
