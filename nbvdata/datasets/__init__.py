"""The jobs on datasets: the generator, publishing and sharing versions, export, the authors' dataset."""
