"""The product: command line, SLAM worker thread and the viser web viewer."""
