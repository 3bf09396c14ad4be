"""Synthesis stages: the novel-pose plan, the CNN-LSTM's training and synthesis, classical baselines."""
