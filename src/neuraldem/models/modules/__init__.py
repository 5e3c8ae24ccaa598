"""Building blocks of the composed models: embeddings, conditioning, attention blocks, encoders, decoders."""
