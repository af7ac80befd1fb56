"""Plots. Every function draws on a given matplotlib ``ax`` from arrays in the local metric frame;
:mod:`featmap.plotting.figures` composes the paper's figures from a run folder."""
