// Encodes a label mask as the PNG the selection API reads: an offscreen canvas of the mask's
// size whose pixels are r = g = b = label and a = 255 (opaque, so no premultiplication can
// change a value), written by the browser's own PNG encoder.

/**
 * @param {Uint8Array} labels width × height labels, row-major
 * @returns {Promise<Blob>} image/png
 */
export function encodeMask(labels, width, height) {
  if (labels.length !== width * height) throw new Error(`mask of ${labels.length} labels is not ${width}x${height}`);
  const canvas = document.createElement('canvas');
  canvas.width = width;
  canvas.height = height;
  const g = canvas.getContext('2d', { willReadFrequently: false });
  const image = g.createImageData(width, height);
  const px = image.data;
  for (let i = 0; i < labels.length; i++) {
    const v = labels[i];
    px[i * 4] = v;
    px[i * 4 + 1] = v;
    px[i * 4 + 2] = v;
    px[i * 4 + 3] = 255;
  }
  g.putImageData(image, 0, 0);
  return new Promise((resolve, reject) => {
    canvas.toBlob((blob) => (blob ? resolve(blob) : reject(new Error('the browser cannot encode the stroke mask as PNG'))), 'image/png');
  });
}
