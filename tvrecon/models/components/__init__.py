"""The networks (plain ``nn.Module``s built from configs): ResNet branches, the tactile-visual fusion, the mesh
deformer, the touch-geometry deformer and the tactile classifiers. The LightningModules that train and test them are
one level up, in :mod:`tvrecon.models`."""
