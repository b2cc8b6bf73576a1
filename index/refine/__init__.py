"""An answer's pose fitted to the frame that asked: the result and rigid-motion algebra they share (`fit`),
the colour fit of the mesh's outline to the image (`colour`) and the depth fit of its surface (`depth`, ICP)."""
