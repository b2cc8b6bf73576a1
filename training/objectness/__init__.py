"""The class-agnostic object-centre network of `index/features/objectness.py`: its training settings
(`config`), samples (`samples`), model and losses (`model`), training and export (`train`), and recall (`recall`).

The frozen ImageNet MobileNetV2 stages (`training/trunk.py`) to stride 8 and 16, and a small trained head
on the stride-8 map (the stride-16 map upsampled beside it; dilated 3 x 3 convolutions so that a cell
sees the whole ~64 px window around it) predicting per cell a centre heatmap (CenterNet's focal loss on
Gaussians around each object's projected origin), the sub-cell offset of the centre, and the log sizes
of the object's 200 mm window and of its projected diameter (L1 at the cells near a centre).

Training samples are crops of real LM-O frames of the TRAIN split, each resized so that one object's
window lands at a random size around `reference_px`, with procedural shapes (`index/templates/shapes.py`) rendered
at random poses and lights and pasted in with soft edges: the network has to find objects it has never
seen, not the seven of LM-O. Objects whose window at the crop's scale is inside `positive_px` are
targets; a band around that range (and objects under `min_visib` visible) is neither target nor
background; objects far out of it are background, so that each object peaks at the pyramid levels
where its window fits. Checkpoints are chosen on the VALIDATION frames' recall.
"""

from training.objectness.config import ObjectnessConfig
from training.objectness.model import ObjectnessNet
from training.objectness.samples import Frame, load_frames
from training.objectness.train import export, load_checkpoint, train

__all__ = ["Frame", "ObjectnessConfig", "ObjectnessNet", "export", "load_checkpoint", "load_frames", "train"]
