"""What the networks see and give: the metric patch around an object (`patches`), the descriptor network
run with onnxruntime (`embed`), the local features the re-ranking compares cell by cell (`local`), and the
objectness network's contract, shared by its training and the detector (`objectness`)."""
