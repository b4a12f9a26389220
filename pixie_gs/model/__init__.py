"""The material network (3D U-Net over a rasteriser-free feature grid), its checkpoints,
training loop, batches and evaluation. Heavy (torch) imports live in the submodules."""
