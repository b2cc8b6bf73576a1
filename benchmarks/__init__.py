"""Measurements that print numbers and never fail on time: `posedesc bench` (one JSON, every figure beside
its baseline) and two older scripts.

- `suite.py`: the sections in one run, the headline figures and the issue's targets; `table.py` prints it.
- `timing.py`: repetitions, medians, percentiles, thread settings, the machine's facts.
- `objects.py`: procedural shapes rendered once, turned into up to 48 x as many distinct objects; the query patch.
- `stores.py`: template stores of many objects, searched by the service's own code.
- `descriptor.py`: our descriptor's throughput (onnxruntime, batch 1 and 256) against HOG.
- `recognition.py`: one recognition against LineMOD at 8, 100, 1,000 objects.
- `knn.py`: k-NN latency and memory from 10^4 to 10^7 templates, exact against IVF, IVF's recall.
- `server.py`, `over_http.py`, `registration.py`: the real service on loopback: `POST /recognize` with
  concurrent clients, `POST /objects` of a 20k-face mesh.
- `train_step.py`: the network's training throughput (torch, imported only there).
- `render.py`, `serving.py`: scripts (`.venv/bin/python benchmarks/render.py`): template rendering with and
  without level of detail; registration per in-plane step and in-process recognition per modality.
"""
