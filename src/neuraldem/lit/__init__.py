"""LightningModules: losses, optimizer (LION), schedules and checkpoint metadata around the nets."""
