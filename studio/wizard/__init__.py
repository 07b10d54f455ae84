"""The guided wizard: one module per step, each holding its GUI handles."""
