"""`neuraldem datagen data=NAME`: run the real solver for a dataset, resumable (see __main__)."""
