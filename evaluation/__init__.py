"""Evaluation as the paper measures it (`posedesc evaluate`). Never imports torch; index/ and service/
never import it.

- `metric.py`: pose errors over retrieved templates and the k = 1…22 accuracy table.
- `templates.py`: the template renders every method is compared on.
- `samples.py`: test patches from real frames, or from synthetic scenes through the sensor model.
- `ours.py`: our descriptors and exact nearest neighbours.
- `hog.py`, `linemod.py`: the two baselines.
- `run.py`: one evaluation, end to end; `report.py`, `pictures.py`: what a person reads.
"""
