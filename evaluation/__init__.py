"""Evaluation as the paper measures it and as the service answers (`posedesc evaluate`). Never imports
torch; index/ and service/ never import it.

- `config.py`: what one evaluation measures; `run.py`: runs it by protocol.
- `served.py`: the service protocol (registration and `recognise`, the open set on); `queries.py`: what a
  user sends about a dataset's instances.
- `paper.py`: the paper's protocols (paper, full): patches cut at the truth, one template set.
- `metric.py`: pose errors over retrieved templates and the k = 1…22 accuracy table.
- `templates.py`: the template renders every method is compared on.
- `samples.py`: test patches from real frames, or from synthetic scenes through the sensor model.
- `methods.py`: the methods by name; `ours.py`: our descriptors and exact nearest neighbours;
  `hog.py`, `linemod.py`: the two baselines.
- `results.py`: the scored answers and the JSON; `report.py`, `pictures.py`: what a person reads.
- `openset.py`, `calibration.py`: answers for the open-set calibration; `rolls.py`, `masks.py`: frames
  turned, masks and depth rendered from the ground truth.
"""
