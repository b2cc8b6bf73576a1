"""An object's templates: a user's mesh loaded and checked (`mesh`, `mesh_limits`), the viewpoints on the
half-sphere (`viewpoints`), rendered headless on EGL (`render`, shaders in `shaders/`), embedded and stored
(`register`, the one registration path), procedural objects (`shapes`) and contact sheets (`sheet`)."""
