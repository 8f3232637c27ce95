"""The base every stage stands on: settings, words, files, users' arrays, view layouts, paths, clouds."""
