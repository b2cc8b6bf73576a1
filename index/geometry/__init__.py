"""Geometry and its conventions, stated once: poses (`pose`), pose errors as BOP defines them
(`pose_error`), an object's symmetries (`symmetry`), a mesh file's units (`units`), each object's patch
window (`windows`), where an object's origin lies behind its surface (`surface`), and the sensor model that
makes clean renders look like a real RGB-D camera's frames (`sensor`)."""
