"""The shared core of posedesc: everything both `training/` and `service/` need, and nothing of either.

Rooms (each package's docstring says what it owns):

- `index.geometry`: poses and their conventions, BOP pose errors, symmetries, units, patch windows, the
  sensor model;
- `index.templates`: an object's templates: meshes in, views rendered on the half-sphere, registration;
- `index.features`: what the networks see and give: patches, the ONNX embedder, local features, objectness;
- `index.store`: where templates are kept and searched: the interface, the embedded and Milvus backends and
  their files;
- `index.refine`: an answer's pose fitted to the frame, in colour and in depth;
- `index.data`: datasets read (BOP format);
- `index.draw`: answers drawn over their image.

Imports go down only, in this order (each room may use the ones before it): `geometry`, `features`,
`store`, `templates` (registration writes to the store), `draw`, `refine`, `data`. `index` never imports
`service`, `training`, `evaluation`, `benchmarks` or `posedesc`; tests/test_house.py holds it to that."""
