"""What is trained on the frozen pretrained trunk besides the descriptor: the local features the re-ranking
compares (`local`), the foreground mask (`mask`, put into an exported model by `graft`), and the PCA
descriptor (`pca`)."""
