//! Constant-strain triangle membrane FEM (Van Gelder Eq. 10-12): the reference answer.
