"""Measurements that print numbers and never fail on time: `posedesc bench` (one JSON, every figure beside
its baseline) and two older scripts.

- `suite.py`: the sections in one run, the headline figures and the issue's targets; `table.py` prints it.
- `timing.py`: repetitions, medians, percentiles, thread settings, the machine's facts.
- `objects.py`: procedural shapes rendered once, turned into up to 48 x as many distinct objects; the query
  patch; templates with in-plane variants (rendered and turned as registration does) for the roll section.
- `stores.py`: template stores of many objects, searched by the service's own code; data dirs filled
  through `Store.add_object`.
- `descriptor.py`: our descriptor's throughput (onnxruntime, batch 1 and 256) against HOG.
- `recognition.py`: one recognition against LineMOD at 8, 100, 1,000 objects.
- `knn.py`: k-NN latency and memory from 10^4 to 10^7 templates, exact against IVF, IVF's recall.
- `server.py`, `over_http.py`, `registration.py`: the real service on loopback: `POST /recognize` with
  concurrent clients, `POST /objects` of a 20k-face mesh.
- `roll.py`: the roll-estimating set-up (in-plane templates, query turns) against the issue's targets, each
  beside its baseline: `service.recognition.recognise_decoded` in-process at 100 objects (vs upright
  templates and LineMOD), a 640x480 frame over HTTP, registration of a 20k-face mesh; the model is a
  parameter (the shipped one, an untrained stand-in of the coming design exported on the spot, a path).
- `guards.py`: how long the service's guards take to refuse: hostile uploads over HTTP, meshes refused from
  what they declare, damaged meshes, `posedesc serve` on a busy port (the tests check only the answers);
  `hostile.py` makes those inputs, for the tests and for it.
- `train_step.py`: the network's training throughput (torch, imported there and, for the roll section's
  stand-in export, in `roll.py`).
- `render.py`, `serving.py`: scripts (`.venv/bin/python benchmarks/render.py`): template rendering with and
  without level of detail; registration per in-plane step and in-process recognition per modality.
"""
