//! The engine's fixed capacities, at the bottom of the rooms so that every user looks down to
//! them.

/// Most fingers the coupled solve takes.
pub const MAX_FINGERS: usize = 4;

/// Most objects in one scene.
pub const MAX_OBJECTS: usize = 4;

/// Most candidate nodes of one object's contact problem (all its spheres together).
pub const MAX_PATCH: usize = 256;
