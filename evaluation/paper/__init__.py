"""The paper's protocols (`posedesc evaluate --protocol paper` and `full`, `protocol`): test patches cut at
the true centre (`samples`), templates shared by every method (`templates`), each method's ranking
(`methods`: ours, HOG, LineMOD; `ours`, `neighbours`) and the paper's metric (`metric`)."""
