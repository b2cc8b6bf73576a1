"""The detect protocol (`posedesc evaluate --protocol detect`): frames sent whole to the service's own
detector (`run`) and its detections scored against the ground truth (`score`)."""
