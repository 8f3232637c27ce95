"""The jobs on datasets: the generator, publishing and cards, export, the authors' dataset."""
